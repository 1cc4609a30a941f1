"""The kinds of scene: what each one labels, learns, reports and exports. Defined once.

A scene's kind (``scenes.<s>.kind`` in params.yaml) is the number of contacts its
conditions place on the skin; everything that differs between kinds is an attribute of
its :class:`Kind`, so the rest of eskin asks the kind instead of testing its name:

* the label columns (``force, x, y`` for one contact; ``force1, x1, y1, force2, x2, y2``
  for two), then ``stretch``;
* whether the labels give each contact's force or only their total: a recording whose
  one force sensor sums two contacts (an import mapping ``force``) is of the kind's
  total-force variant (:meth:`Kind.with_total_force`), which trains that total and the
  positions and says it cannot give per-contact forces (:data:`TOTAL_FORCE_ONLY`). A
  dataset's kind is its scene's, read with its ``eskin.labels`` metadata
  (:func:`kind_of_labels`); the variant's name is what its scores and stack record;
* the file widths an import accepts (the paper's two-contact files have no stretch);
* the strata of cross-validation (the node, or the pair of nodes);
* what the detect task learns: whether a contact presses (one contact), or how many of
  the contacts press (several: 0, 1 or 2 with two; a scene recorded with fewer contacts
  on some conditions, ``scenes.<s>.contact_counts``, has something to count);
* the stack's outputs, with and without a detector (the report's headline rows and
  figures of each kind are the report's: eskin.reporting.presentation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from eskin.skin import AnySkin

# Why a recording of several contacts' total force has no per-contact force scores.
TOTAL_FORCE_ONLY = "the recording gives the total force only: no per-contact forces"


@dataclass(frozen=True)
class Kind:
    """A kind of scene: ``contacts`` indenters per condition; ``total_force``: its labels
    give only the contacts' total force (a variant of the kind ``scene_kind``, which
    params.yaml names)."""

    name: str
    contacts: int
    # The paper's two-contact files carry no stretch column (λ = 1): an import may omit it.
    stretch_column_optional: bool
    total_force: bool = False
    scene_kind: str = ""   # default: the name
    label: str = ""        # default: the name in words

    def __post_init__(self) -> None:
        object.__setattr__(self, "scene_kind", self.scene_kind or self.name)
        object.__setattr__(self, "label", self.label or self.name.replace("_", " "))

    def _suffixes(self) -> list[str]:
        return [""] if self.contacts == 1 else [str(i) for i in range(1, self.contacts + 1)]

    def with_total_force(self) -> Kind:
        """This kind labelled with its contacts' total force only."""
        if self.name not in TOTAL_FORCE_KINDS:
            raise ValueError(f"a {self.name} scene has no total-force variant: its force "
                             "is already its one contact's")
        return TOTAL_FORCE_KINDS[self.name]

    @property
    def force_columns(self) -> list[str]:
        """Each contact's force, or ``force``: one contact's, or the total of several."""
        if self.total_force:
            return ["force"]
        return [f"force{s}" for s in self._suffixes()]

    @property
    def weighed_contacts(self) -> dict[str, list[str]]:
        """Each force column → the x columns of the contacts it weighs (node 0: none)."""
        if self.total_force:
            return {"force": [f"x{s}" for s in self._suffixes()]}
        return {f"force{s}": [f"x{s}"] for s in self._suffixes()}

    @property
    def positions(self) -> dict[str, tuple[str, str]]:
        """Each contact's position (``position``, or ``position1``…) → its (x, y) columns."""
        return {f"position{s}": (f"x{s}", f"y{s}") for s in self._suffixes()}

    @property
    def node_columns(self) -> list[str]:
        """x then y of each contact: ``x, y`` or ``x1, y1, x2, y2``."""
        return [f"{axis}{s}" for s in self._suffixes() for axis in ("x", "y")]

    @property
    def contact_columns(self) -> list[tuple[str, str, str]]:
        """(force, x, y) column names of each contact, in label order, where the labels give
        each contact's force (an acquisition's)."""
        return [(f"force{s}", f"x{s}", f"y{s}") for s in self._suffixes()]

    @property
    def labels(self) -> list[str]:
        """The label columns of a dataset, in file order: each contact's force, x, y (or
        the total force, then each contact's x, y), then stretch."""
        if self.total_force:
            return [*self.force_columns, *self.node_columns, "stretch"]
        return [name for contact in self.contact_columns for name in contact] + ["stretch"]

    def file_widths(self, skin: AnySkin) -> tuple[int, ...]:
        """The column counts an imported file of this kind may have."""
        full = skin.terminals + len(self.labels)
        return (full - 1, full) if self.stretch_column_optional else (full,)

    def file_labels(self, width: int, skin: AnySkin) -> list[str]:
        """The label columns of an imported file ``width`` columns wide."""
        return self.labels if width == skin.terminals + len(self.labels) else self.labels[:-1]

    @property
    def several(self) -> bool:
        """Several contacts per condition: a plan places them from node lists, each pressing
        with a force > 0 (``contact_counts`` may leave some off); they are paired and
        scored as a set, may be weighed by one sensor (a total-force variant), and an
        import keeps the rows where they press (its rows at rest teach nothing)."""
        return self.contacts > 1

    def in_label_order(self, labels: dict[str, np.ndarray], skin: AnySkin
                       ) -> dict[str, np.ndarray]:
        """``labels`` (column → values) with each row's contacts in label order, as a plan
        names them (eskin.data.plan): by node (x, then y), an absent contact (node 0)
        last. A group a recording lacks (per-contact forces, where it gives their total) is
        passed over."""
        if not self.several:
            return labels
        nodes = np.stack([skin.node_id(np.nan_to_num(labels[x]), np.nan_to_num(labels[y]))
                          for _, x, y in self.contact_columns], axis=1)
        order = np.argsort(np.where(nodes > 0, nodes, skin.n_nodes + 1), axis=1,
                           kind="stable")
        out = dict(labels)
        for group in zip(*self.contact_columns, strict=True):  # the forces, the xs, the ys
            if all(column in labels for column in group):
                values = np.take_along_axis(np.stack([labels[c] for c in group], axis=1),
                                            order, axis=1)
                out.update({column: values[:, i] for i, column in enumerate(group)})
        return out

    @property
    def detect_target(self) -> str | None:
        """The detect task's target: ``contact`` (one contact: pressed or not) or
        ``contacts`` (several: how many press, 0 to :attr:`contacts`); None for a kind
        that places no contact."""
        if not self.contacts:
            return None
        return "contact" if self.contacts == 1 else "contacts"

    @property
    def detect_scorer(self) -> str:
        """How the detect task is scored (eskin.evaluation.metrics.SCORERS)."""
        return "detection" if self.contacts == 1 else "counting"

    def strata(self, frame, skin: AnySkin) -> np.ndarray:
        """The stratum of each row for CV: its node, or its combination of nodes."""
        out = np.zeros(len(frame), dtype=np.int64)
        for x, y in self.positions.values():
            node = skin.node_id(frame[x], frame[y])
            out = out * (skin.n_nodes + 1) + node
        return out

    def stack_outputs(self, counted: bool) -> list[str]:
        """The estimates a stack gives for each frame, in order. A one-contact stack always
        says whether a contact presses (every frame does, without a detector); a
        several-contact stack says it, and how many press (``contacts``), only where
        ``counted``: where its scene had samples with fewer contacts to learn from."""
        if self.contacts == 1:
            return ["stretch", "contact", "contact_probability", *self.node_columns,
                    *self.force_columns]
        if counted:
            return ["stretch", "contact", "contact_probability", "contacts",
                    *self.node_columns, *self.force_columns]
        return ["stretch", *self.node_columns, *self.force_columns]


ONE_CONTACT = Kind("single_force", contacts=1, stretch_column_optional=False)

TWO_CONTACTS = Kind("two_force", contacts=2, stretch_column_optional=True)

# Two contacts under one force sensor: the total force and the pair of positions.
TWO_CONTACTS_TOTAL_FORCE = Kind(
    "two_force_total", contacts=2, stretch_column_optional=True, total_force=True,
    scene_kind=TWO_CONTACTS.name, label="two force, total force only",
)

KINDS: dict[str, Kind] = {kind.name: kind for kind in (ONE_CONTACT, TWO_CONTACTS)}
KIND_NAMES: tuple[str, ...] = tuple(KINDS)
# A scene kind's variant whose labels give the contacts' total force only.
TOTAL_FORCE_KINDS: dict[str, Kind] = {TWO_CONTACTS.name: TWO_CONTACTS_TOTAL_FORCE}
# Every kind a dataset can have: the scene kinds and their variants.
DATASET_KINDS: dict[str, Kind] = {**KINDS, **{kind.name: kind
                                              for kind in TOTAL_FORCE_KINDS.values()}}


def get_kind(name: str) -> Kind:
    """The kind called ``name`` (a scene kind or a variant); an error listing the scene
    kinds."""
    try:
        return DATASET_KINDS[name]
    except KeyError:
        raise ValueError(f"unknown scene kind {name!r}; known: {', '.join(KINDS)}") from None


def kind_of_labels(name: str, labels: list[str] | None) -> Kind:
    """The kind of a dataset of a ``name`` scene whose label columns are ``labels`` (its
    ``eskin.labels`` metadata; None: the scene kind's own)."""
    declared = get_kind(name)
    if labels is None:
        return declared
    for kind in DATASET_KINDS.values():
        if kind.scene_kind == declared.scene_kind and kind.labels == list(labels):
            return kind
    known = " or ".join(", ".join(kind.labels) for kind in DATASET_KINDS.values()
                        if kind.scene_kind == declared.scene_kind)
    raise ValueError(f"labels {', '.join(labels)} are not those of a {name} dataset "
                     f"({known})")
