"""The headline table, the report page and the results page (``reports/results.md``).

Inputs are the scores documents of the training and scoring stages; outputs
are strings, so that everything here is tested without files.
"""

from __future__ import annotations

import base64
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from eskin.catalog import SCHEME_NOTES, SCHEMES
from eskin.kinds import ONE_CONTACT, TWO_CONTACTS, get_kind
from eskin.reporting.presentation import Headline, headlines
from eskin.skin import PAPER_SKIN, AnySkin

# (scene, kind, skin, {task: scores document}) for each scene of params.yaml, in its order.
Scenes = list[tuple[str, str, AnySkin, Mapping[str, Mapping]]]

# The headline tables' column of each scheme.
SCHEME_HEADINGS = {"stratified": "stratified CV (the paper's)",
                   "conditions": "conditions CV (whole conditions out)",
                   "trials": "trials CV (new trials of seen conditions)"}


def score_text(scores: Mapping[str, Mapping], row: Headline, scheme: str) -> str:
    """A headline's value under ``scheme`` as ``mean ± std`` (or missing, skipped, —)."""
    document = scores.get(row.task)
    if document is None:
        return "missing"
    if document.get("status") == "skipped":
        return "skipped"
    scores = document.get(scheme, {})
    if row.target is not None:
        scores = scores.get(row.target, {})
    if row.metric not in scores:
        return "—"
    mean, std = scores[row.metric], scores.get(f"{row.metric}_std", float("nan"))
    if not math.isfinite(mean):
        return "n/a"
    digits = 3 if abs(mean) >= 1e-3 or mean == 0 else 2
    fmt = f"{{:.{digits}f}}" if digits == 3 else "{:.2e}"
    return f"{fmt.format(mean)} ± {fmt.format(std)}" if math.isfinite(std) else fmt.format(mean)


def scored_schemes(scores: Mapping[str, Mapping]) -> list[str]:
    """The schemes a scene's tasks were scored under, in :data:`SCHEMES`' order: always the
    paper's and conditions; ``trials`` where the scene's data allowed it (repeats ≥ 2)."""
    return [s for s in SCHEMES if s in ("stratified", "conditions")
            or any(s in (document or {}) for document in scores.values())]


# The kinds the paper measured (its III-D and III-E), on its skin: only their scenes'
# tables have a "paper" column. Another skin's numbers (a magnetic array's, a 16 × 16's)
# are not the paper's capacitive skin's to be set beside.
PAPER_KINDS = (ONE_CONTACT.name, TWO_CONTACTS.name)


def beside_the_paper(kind: str, skin: AnySkin = PAPER_SKIN) -> bool:
    """Whether a ``kind`` scene on ``skin`` is the paper's setting: its kind on its skin."""
    return kind in PAPER_KINDS and skin == PAPER_SKIN


def headline_columns(scores: Mapping[str, Mapping], kind: str = ONE_CONTACT.name,
                     skin: AnySkin = PAPER_SKIN) -> list[str]:
    """The headline table's heading: metric, a column per scored scheme, and paper
    where the scene is the paper's setting (:func:`beside_the_paper`)."""
    paper = ["paper"] if beside_the_paper(kind, skin) else []
    return ["metric", *(SCHEME_HEADINGS[s] for s in scored_schemes(scores)), *paper]


def headline_rows(kind: str, scores: Mapping[str, Mapping], skin: AnySkin = PAPER_SKIN
                  ) -> list[list[str]]:
    """[metric, each scored scheme (:func:`scored_schemes`), paper (:func:`headline_columns`)]
    per headline of a ``kind`` scene on ``skin`` whose scores documents are ``scores`` (by
    task), as display strings."""
    schemes = scored_schemes(scores)
    paper = beside_the_paper(kind, skin)
    return [[_label(scores, row), *(score_text(scores, row, s) for s in schemes),
             *([row.paper] if paper else [])]
            for row in headlines(get_kind(kind)) if not row.optional or _scored(scores, row)]


def _scored(scores: Mapping[str, Mapping], row: Headline) -> bool:
    """Whether any scheme of the row's scores document has its metric."""
    document = scores.get(row.task) or {}
    return any(row.metric in (document.get(scheme) or {}).get(row.target, {})
               for scheme in SCHEMES)


def skin_note(skin: AnySkin) -> str:
    """The skin a scene is on, as the page and the results say it: nothing for the paper's
    (every scene's, unless params.yaml says otherwise, and so its pages keep their bytes)."""
    return "" if skin == PAPER_SKIN else skin.describe()


def _label(scores: Mapping[str, Mapping], row: Headline) -> str:
    """The row's label with the model that produced its number (the paper's, or another)."""
    model = scores.get(row.task, {}).get("model")
    return f"{row.label} [{model}]" if model else row.label


def headline_markdown(kind: str, scores: Mapping[str, Mapping], skin: AnySkin = PAPER_SKIN
                      ) -> str:
    columns = headline_columns(scores, kind, skin)
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(cells) + " |" for cells in headline_rows(kind, scores, skin)]
    return "\n".join(lines)


def dataset(scores: Mapping[str, Mapping]) -> tuple[str, str, str] | None:
    """(DVC md5, rows, source) of the dataset a scene's tasks trained on."""
    for document in scores.values():
        if "dataset_md5" in document:
            rows = document.get("dataset_rows")
            return (document["dataset_md5"], f"{rows:,}" if isinstance(rows, int) else "?",
                    str(document.get("source", "?")))
    return None


def skipped(scores: Mapping[str, Mapping]) -> list[tuple[str, str]]:
    """(task, reason) of each task the scene's data did not support, and (``pairs force
    scores``, reason) of the scores a task that ran could not give (``skipped_scores``)."""
    return [(task, str(document.get("reason", "")))
            for task, document in scores.items() if document.get("status") == "skipped"] + [
        (f"{task} {what} scores", str(reason)) for task, document in scores.items()
        for what, reason in (document.get("skipped_scores") or {}).items()]


def fold_notes(scores: Mapping[str, Mapping]) -> list[tuple[str, str]]:
    """(scheme, note) of each CV scheme whose folds fell back from the node strata (the
    folds step's ``fold_notes``, which every task of the scene carries alike)."""
    notes: dict[str, str] = {}
    for document in scores.values():
        notes.update(document.get("fold_notes") or {})
    return list(notes.items())


def results_markdown(scenes: Scenes) -> str:
    """The results page: each scene's dataset version and headline table beside the paper.

    A file of its own, not a section of the README: written into the README, every
    experiment rewrote it, and a prose edit made `dvc status` report a changed output."""
    parts = ["# Results",
             "Written by the report (the publish stage) from the scores of this commit "
             "(`reports/scores/`; `dvc metrics show` has the conditions-CV headline, and "
             "the figures and the model hashes are in `reports/index.html`)."]
    for scene, kind, skin, scores in scenes:
        data = dataset(scores)
        about = (f"{data[1]} rows, {data[2]}, DVC md5 `{data[0]}`" if data
                 else "no trained task")
        if skin_note(skin):
            about += f"; skin: {skin_note(skin)}"
        skips = "".join(f"\n- {scene}/{task} skipped: {reason}"
                        for task, reason in skipped(scores))
        skips += "".join(f"\n- {scene} {scheme} CV folds: {note}"
                         for scheme, note in fold_notes(scores))
        parts.append(f"## {scene} ({get_kind(kind).label})\n\n{about}.\n\n"
                     f"{headline_markdown(kind, scores, skin)}" + (f"\n{skips}" if skips else ""))
    return "\n\n".join(parts) + "\n\nMean ± std over folds.\n"


CSS = """
body { font-family: system-ui, sans-serif; max-width: 2300px; margin: 2em auto; padding: 0 2em;
       color: #222; line-height: 1.4; }
h1 { font-size: 1.6em; margin-bottom: 0.3em; }
.intro { max-width: 70em; }
.top { display: flex; flex-wrap: wrap; gap: 1.5em; align-items: flex-start; }
table.run { margin: 0; }
table.run caption { text-align: left; font-weight: bold; padding-bottom: 0.3em; }
table { border-collapse: collapse; margin: 1em 0; font-size: 0.92em; }
th, td { border: 1px solid #ccc; padding: 0.3em 0.6em; text-align: left; }
th { background: #f3f3f3; }
table:not(.run) td:nth-child(2), td:nth-child(3) {
  font-variant-numeric: tabular-nums; white-space: nowrap; }
nav#contents { background: #f7f7f7; border: 1px solid #e3e3e3; padding: 0.4em 1.2em; }
nav#contents h2 { font-size: 1.1em; margin: 0.4em 0; }
nav#contents ol { margin: 0.2em 0; padding-left: 1.4em; }
section.figure { margin: 1.5em 0 2.5em; }
section.figure h3 { margin-bottom: 0.2em; }
section.figure > p { margin-top: 0; color: #444; }
/* a figure's CV schemes side by side where each is shown at least --legible wide (its
   smallest text TEXT_PX high: page.py Rendering.legible_width); else one under the other */
.schemes { display: grid; gap: 1.2em; align-items: start;
           grid-template-columns: repeat(auto-fit, minmax(min(100%, var(--legible)), 1fr)); }
figure { margin: 0; }
figure img { box-sizing: border-box; width: 100%; height: auto; border: 1px solid #eee; }
figcaption { font-size: 0.9em; color: #555; }
"""


# The size (CSS px, the font's) that a figure's smallest text has on the page at least,
# where the window allows. At 1,400 px: two page-wide figures of 9 pt text side by side
# (11.4 px), a confusion matrix of 10 classes (5 pt) alone on its row (12.9 px); from a
# 2,300 px window on, it too side by side (10.7 px).
TEXT_PX = 10.5
IMG_BORDER_PX = 1


@dataclass(frozen=True)
class Rendering:
    """A figure's PNG for the page, its width (inches) and its smallest text (points)."""

    png: bytes
    width_in: float
    smallest_pt: float

    def legible_width(self) -> int:
        """The width (CSS px, border included) at which the figure's smallest text is
        :data:`TEXT_PX` high."""
        inch = TEXT_PX * 72 / self.smallest_pt  # CSS px to the figure's inch
        return math.ceil(self.width_in * inch) + 2 * IMG_BORDER_PX


@dataclass
class FigureRow:
    """One figure of a scene on the page: its CV schemes' renderings side by side, each
    (scheme, heading: what it shows, its rendering)."""

    id: str
    file: str      # the figure's file name without scheme and suffix (its id in kinds.py)
    title: str
    caption: str
    schemes: list[tuple[str, str, Rendering]] = field(default_factory=list)

    def legible_width(self) -> int:
        return max((shown.legible_width() for *_, shown in self.schemes), default=0)


@dataclass(frozen=True)
class Provenance:
    """Which run the page shows: under ``dvc exp run``, the experiment and the commit it
    ran on top of (its baseline); under a plain ``dvc repro``, neither (see
    :func:`eskin.reporting.report.provenance`)."""

    commit: str = ""
    experiment: str = ""

    @property
    def short(self) -> str:
        return self.commit[:8]

    def headline(self) -> str:
        """The page's title: which commit and experiment."""
        if self.experiment and self.commit:
            return f"experiment {self.experiment}, run on top of commit {self.short}"
        if self.experiment:
            return f"experiment {self.experiment}"
        return "the checked-out pipeline, no experiment"


def models(scenes: Scenes) -> list[list[str]]:
    """(scene/task, model, model md5) of each trained task: the key to its MLflow run."""
    return [[f"{scene}/{task}", str(document.get("model", "?")), document["model_md5"]]
            for scene, _, _, scores in scenes for task, document in scores.items()
            if "model_md5" in document]


def model_variants(scenes: Scenes) -> list[tuple[str, str]]:
    """(scene, "task model, …") of each scene: which model each of its tasks trained, as
    its scores files say (what an experiment changes)."""
    return [(scene, ", ".join(f"{task} {document['model']}" for task, document in
                              scores.items() if "model_md5" in document and "model" in document))
            for scene, _, _, scores in scenes]


def render_page(scenes: Scenes, figures: Mapping[str, list[FigureRow]],
                run: Provenance | None = None, figures_href: str = "figures",
                model_runs: Callable[[str], str] | None = None) -> str:
    """The report (templates/page.html.j2): which run it is, a table of contents, then
    per scene its headline table, dataset and figures (each figure's CV schemes side by
    side, embedded as PNG), then the models. The page needs no other file; it links each
    figure's full-size files (``figures_href``: their directory, from the page's) and,
    given ``model_runs`` (a model md5 → the MLflow UI's page of its runs), each model's
    runs."""
    import jinja2

    environment = jinja2.Environment(
        loader=jinja2.PackageLoader("eskin.reporting", "templates"),
        autoescape=True, undefined=jinja2.StrictUndefined)
    context = [{
        "name": scene, "kind": get_kind(kind).label, "skin": skin_note(skin),
        "dataset": dict(zip(("md5", "rows", "source"), data, strict=True)) if (
            data := dataset(scores)) else None,
        "headline": headline_rows(kind, scores, skin),
        "columns": headline_columns(scores, kind, skin),
        "skipped": skipped(scores),
        "fold_notes": fold_notes(scores),
        "figures": [{"id": row.id, "title": row.title, "caption": row.caption,
                     "legible": row.legible_width(),
                     "schemes": [{"scheme": scheme, "id": f"{row.id}_{scheme}",
                                  "file": f"{figures_href}/{scene}/{row.file}_{scheme}",
                                  "heading": heading, "note": SCHEME_NOTES[scheme],
                                  "png": base64.b64encode(shown.png).decode()}
                                 for scheme, heading, shown in row.schemes]}
                    for row in figures.get(scene, [])],
    } for scene, kind, skin, scores in scenes]
    return environment.get_template("page.html.j2").render(
        css=CSS, scenes=context, run=run or Provenance(),
        models=[(*row, model_runs(row[2]) if model_runs else None) for row in models(scenes)],
        variants=model_variants(scenes))
