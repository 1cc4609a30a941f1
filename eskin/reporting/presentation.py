"""What the report shows of each kind of scene: its headline rows (where each number is,
and the paper's value) and its figures. Presentation only: an edit here reruns the publish
stage (the report, and MLflow's runs, which log the headline and attach the figures),
nothing else.
"""

from __future__ import annotations

from dataclasses import dataclass

from eskin.kinds import ONE_CONTACT, TWO_CONTACTS, TWO_CONTACTS_TOTAL_FORCE, Kind


@dataclass(frozen=True)
class Headline:
    """One row of a scene's headline table: where its number is, and the paper's value."""

    label: str
    task: str
    target: str | None     # None: the scores sit directly under the scheme (pairs)
    metric: str
    paper: str = "—"
    # Shown only where the scores have it: the position error in mm, of a skin that
    # places its nodes in mm.
    optional: bool = False


# A figure's id names its file, ``reports/figures/<scene>/<id>_<scheme>.png`` (and .svg),
# and its place on the report page: the same id for the same figure of either kind (the
# scene's directory says which scene).
STRETCH_PARITY = "stretch_parity"
FORCE_PARITY = "force_parity"
LOCALISATION_CONFUSION = "localisation_confusion"
DETECTION = "detection"
FIGURE_IDS: tuple[str, ...] = (STRETCH_PARITY, FORCE_PARITY, LOCALISATION_CONFUSION, DETECTION)


@dataclass(frozen=True)
class Figure:
    """One figure of a scene's report: drawn by the drawer ``draw`` names (registered in
    eskin.reporting.figures with ``@drawer``) from one task's out-of-fold predictions under
    one CV scheme. A name, not the function: so this module imports no matplotlib, and
    what reads the headlines here (the tracking, the CLI) does not load it.

    ``scores`` are the (target, metric) pairs of the task's scores file the figure states
    in its heading beside the scene, task, scheme and n; the first is its headline."""

    id: str
    task: str
    caption: str
    draw: str
    scores: tuple[tuple[str, str], ...]
    targets: tuple[str, ...] = ()   # a confusion grid's targets, with their axes' names
    axis_labels: tuple[str, ...] = ()  # (x, y, …): the report adds "terminal" or "position"
    title: str = ""                 # what the figure shows, in a few words

    def __post_init__(self) -> None:
        if self.id not in FIGURE_IDS:
            raise ValueError(f"figure id {self.id!r} is not one of {', '.join(FIGURE_IDS)}")


TWO_CONTACTS_STRETCH = Figure(
    STRETCH_PARITY, "stretch", "Stretch: predicted against true λ, every prediction and the "
    "mean ± std per level", "stretch_parity", (("stretch", "r2"), ("stretch", "mse")),
    title="stretch parity")
TWO_CONTACTS_LOCALISATION = Figure(
    LOCALISATION_CONFUSION, "localise", "Localisation of two contacts: x and y terminal of "
    "contact 1 (top) and contact 2 (bottom), counts and the share of the samples with that "
    "true terminal (paper Fig. 8)", "confusion_grid",
    (("x1", "accuracy"), ("y1", "accuracy"), ("x2", "accuracy"), ("y2", "accuracy")),
    ("x1", "y1", "x2", "y2"), ("x1", "y1", "x2", "y2"), "localisation, two contacts")

def _two_contact_rows(prefix: str, paper: str = "—") -> tuple[Headline, ...]:
    """The rows a two-contact scene has whatever its force labels: each contact's place
    (``paper``: the paper's word on it), and the pair scored as a set."""
    return (
        # a scene recorded with fewer contacts on some conditions (contact_counts) counts
        Headline(f"{prefix}: contact count accuracy (0, 1 or 2)", "detect", "contacts",
                 "accuracy", optional=True),
        Headline(f"{prefix}: any-contact accuracy", "detect", "contacts",
                 "contact_accuracy", optional=True),
        *(Headline(f"{prefix}: {t} accuracy", "localise", t, "accuracy", paper)
          for t in ("x1", "y1", "x2", "y2")),
        *(Headline(f"{prefix}: contact {i} localisation error (mm)", "localise",
                   f"position{i}", "error_mm", optional=True) for i in (1, 2)),
        Headline(f"{prefix}: pair accuracy, order-free", "pairs", None, "pair_accuracy"),
        Headline(f"{prefix}: pair accuracy, in label order", "pairs", None,
                 "pair_accuracy_ordered"),
        Headline(f"{prefix}: contact accuracy, order-free", "pairs", None,
                 "contact_accuracy"),
        Headline(f"{prefix}: ghost pairs (the other pairing of the same rows and columns)",
                 "pairs", None, "ghost_share"),
    )


HEADLINES: dict[str, tuple[Headline, ...]] = {
    ONE_CONTACT.name: (
        Headline("stretch R²", "stretch", "stretch", "r2", "0.996"),
        Headline("stretch MSE", "stretch", "stretch", "mse", "2 × 10⁻⁵"),
        Headline("force R²", "force", "force", "r2", "0.827"),
        Headline("force RMSE (N)", "force", "force", "rmse"),
        Headline("contact detection accuracy", "detect", "contact", "accuracy", "0.96"),
        Headline("contact detection balanced accuracy", "detect", "contact",
                 "balanced_accuracy"),
        Headline("contact detection ROC AUC", "detect", "contact", "roc_auc"),
        Headline("x accuracy", "localise", "x", "accuracy", "“effective” (Fig. 7)"),
        Headline("x within one node", "localise", "x", "within_one"),
        Headline("y accuracy", "localise", "y", "accuracy", "“effective” (Fig. 7)"),
        Headline("y within one node", "localise", "y", "within_one"),
        Headline("localisation error (mm)", "localise", "position", "error_mm", optional=True),
    ),
    TWO_CONTACTS.name: (
        Headline("two forces: stretch R²", "stretch", "stretch", "r2"),
        Headline("two forces: force 1 R²", "force", "force1", "r2", "0.695"),
        Headline("two forces: force 2 R²", "force", "force2", "r2", "0.771"),
        *_two_contact_rows("two forces", "“high” (Fig. 8)"),
        Headline("two forces: force R², order-free", "pairs", None, "force_r2"),
    ),
    # No paper column: the paper weighed each contact.
    TWO_CONTACTS_TOTAL_FORCE.name: (
        Headline("two contacts: stretch R²", "stretch", "stretch", "r2"),
        Headline("two contacts: total force R²", "force", "force", "r2"),
        Headline("two contacts: total force RMSE (N)", "force", "force", "rmse"),
        *_two_contact_rows("two contacts"),
    ),
}

FIGURES: dict[str, tuple[Figure, ...]] = {
    ONE_CONTACT.name: (
        Figure(STRETCH_PARITY, "stretch", "Stretch: predicted against true λ, every prediction "
               "and the mean ± std per level (paper Fig. 5)", "stretch_parity",
               (("stretch", "r2"), ("stretch", "mse")), title="stretch parity"),
        Figure(FORCE_PARITY, "force", "Force: predicted against true force, mean ± std per "
               "level and stretch, the stretches set side by side about their level; "
               "right, the std per level in newtons (paper Fig. 6)", "force_parity",
               (("force", "r2"), ("force", "rmse")), title="force parity"),
        Figure(LOCALISATION_CONFUSION, "localise", "Localisation of a single contact, on "
               "the contact samples (the detector decides first): x and y terminal, counts "
               "and the share of the samples with that true terminal (paper Fig. 7)",
               "confusion_grid", (("x", "accuracy"), ("y", "accuracy")), ("x", "y"),
               ("x", "y"), "localisation, one contact"),
        Figure(DETECTION, "detect", "Contact detection: confusion counts and shares; the DET "
               "curve (missed against false contacts, on log axes, every decade of the rare "
               "errors) with the model's decisions and their counts", "detection",
               (("contact", "accuracy"), ("contact", "balanced_accuracy")),
               title="contact detection"),
    ),
    TWO_CONTACTS.name: (
        TWO_CONTACTS_STRETCH,
        TWO_CONTACTS_LOCALISATION,
        Figure(FORCE_PARITY, "force", "Force of contact 1 and contact 2: predicted against "
               "true force, mean ± std per level, the std in newtons written beside each "
               "level (paper Fig. 9)", "two_force_parity",
               (("force1", "r2"), ("force2", "r2")), title="force parity, two contacts"),
    ),
    TWO_CONTACTS_TOTAL_FORCE.name: (
        TWO_CONTACTS_STRETCH,
        TWO_CONTACTS_LOCALISATION,
        Figure(FORCE_PARITY, "force", "Total force of the two contacts: predicted against "
               "true, every prediction (the recording gives no force per contact)",
               "total_force_parity", (("force", "r2"), ("force", "rmse")),
               title="total force parity, two contacts"),
    ),
}


def headlines(kind: Kind) -> tuple[Headline, ...]:
    """The headline rows of a ``kind`` dataset (eskin.kinds)."""
    return HEADLINES[kind.name]


def figures(kind: Kind) -> tuple[Figure, ...]:
    """The figures of a ``kind`` dataset's report."""
    return FIGURES[kind.name]
