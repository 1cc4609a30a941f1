"""Pipeline step of reporting: figures, DVC plot data, the report page, the results page.

Reads only the training stages' predictions and scores, the scene list
(``scenes:``, names, kinds and skins) and its own params (``report:``), so a change
of figure style reruns only this step. Every scene gets its own figures,
plot data and section; what a figure shows follows the scene's kind, and its skin: a
row/column skin's nodes are terminals, a channel array's press positions.
"""

from __future__ import annotations

import hashlib
import io
import json
import multiprocessing
import os
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from importlib.metadata import version
from pathlib import Path
from typing import Any

import joblib
import pandas as pd
from joblib import Memory

from eskin.catalog import HEADLINE_SCHEME, PAIRS, PAIRS_HEADLINE, SCHEME_NOTES, TASK_NAMES
from eskin.config.report import Report
from eskin.config.scenes import Scene, scene_kind, scene_skin
from eskin.data.schema import force_columns, node_columns
from eskin.evaluation.outputs import write_json
from eskin.kinds import get_kind
from eskin.reporting import presentation
from eskin.reporting.page import (
    FigureRow,
    Provenance,
    Rendering,
    render_page,
    results_markdown,
    score_text,
)
from eskin.reporting.presentation import Figure, Headline
from eskin.skin import AnySkin


def node_word(skin: AnySkin) -> str:
    """What a node along an axis is on ``skin``: a row/column skin's terminal, or a channel
    array's press position."""
    return "terminal" if skin.row_column else "position"


def draw(figure: Figure, oof: pd.DataFrame, skin: AnySkin):
    """One of a kind's figures (eskin/kinds.py) from its task's out-of-fold predictions on
    ``skin``."""
    from eskin.reporting import figures as fig  # matplotlib: only where a figure is drawn

    build = fig.DRAWERS.get(figure.draw)
    if build is None:
        raise ValueError(f"figure {figure.id!r} ({figure.task}) is drawn by {figure.draw!r}, "
                         "which eskin/reporting/figures.py does not register; register it "
                         f"with @drawer, or name one of {', '.join(sorted(fig.DRAWERS))}")
    if figure.targets:
        return build(oof, list(figure.targets),
                     [f"{axis} {node_word(skin)}" for axis in figure.axis_labels],
                     title=figure.title)
    return build(oof)


METRIC_LABELS = {"r2": "R²", "mse": "MSE", "rmse": "RMSE", "accuracy": "accuracy",
                 "balanced_accuracy": "balanced accuracy", "error_mm": "error (mm)"}
# Errors of a force are in newtons (force, force1, force2); the other scores have no unit.
IN_NEWTONS = ("rmse", "mae")


def scores_line(spec: Figure, document: Mapping | None, scheme: str) -> str:
    """The scores a figure states, from its task's scores file under ``scheme``: ``force
    R² 0.941 ± 0.010 · RMSE 0.477 ± 0.049 N``, or one metric of several targets
    ``accuracy: x1 0.99 ± 0.01, y1 …``."""
    scores = {spec.task: document} if document else {}

    def value(target: str, metric: str) -> str:
        row = Headline(METRIC_LABELS.get(metric, metric), spec.task, target, metric)
        unit = " N" if target.startswith("force") and metric in IN_NEWTONS else ""
        return score_text(scores, row, scheme) + unit

    targets = list(dict.fromkeys(t for t, _ in spec.scores))
    metrics = list(dict.fromkeys(m for _, m in spec.scores))
    if len(targets) > 1 and len(metrics) == 1:
        return f"{METRIC_LABELS.get(metrics[0], metrics[0])}: " + ", ".join(
            f"{t} {value(t, metrics[0])}" for t in targets)
    return " · ".join(f"{target + ' ' if i == 0 or len(targets) > 1 else ''}"
                      f"{METRIC_LABELS.get(metric, metric)} {value(target, metric)}"
                      for i, (target, metric) in enumerate(spec.scores))


@dataclass(frozen=True)
class Identity:
    """What one figure file shows: the lines written at its top, and its metadata."""

    heading: str
    title: str
    description: str


def identity(scene: str, spec: Figure, scheme: str, oof: pd.DataFrame,
             document: Mapping | None) -> Identity:
    """The scene, task, CV scheme (with its folds), n and the headline scores of one figure,
    as the figure states them (three lines) and as its file's metadata."""
    folds = oof["fold"].nunique() if "fold" in oof else 0
    model = (document or {}).get("model")
    line1 = (f"{scene} · {spec.task} · {scheme} CV"
             + (f", {folds} folds" if folds else "") + f" ({SCHEME_NOTES[scheme]})")
    line2 = f"n = {len(oof):,} out-of-fold predictions" + (f" · model {model}" if model else "")
    line3 = scores_line(spec, document, scheme)
    title = f"{scene}: {spec.title} — {scheme} CV"
    return Identity(f"{line1}\n{line2}\n{line3}", title,
                    f"{line1}; {line2}; {line3}. {spec.caption}")


def save(figure, about: Identity, dpi: int) -> tuple[bytes, bytes]:
    """A figure's PNG and SVG bytes, its identity in each file's metadata (PNG tEXt/iTXt
    Title and Description; SVG <title> and dc:description) and nothing that changes from
    one run to the next (no date, no software version)."""
    meta = {"Title": about.title, "Description": about.description}
    png, svg = io.BytesIO(), io.BytesIO()
    figure.savefig(png, format="png", dpi=dpi, metadata={**meta, "Software": None})
    # The constrained layout, found while drawing the PNG, is kept for the other files:
    # finding it again was a third of the report's time.
    figure.set_layout_engine("none")
    figure.savefig(svg, format="svg", metadata={**meta, "Date": None})
    return png.getvalue(), svg.getvalue()


@dataclass(frozen=True)
class FigureJob:
    """One figure to draw: ``spec`` from ``oof`` on ``skin``, its files at ``dpi``, and
    rendered at ``page_dpi`` for the page. All that decides its pixels, and nothing else
    (not where it is saved): the figure cache's key."""

    spec: Figure
    oof: pd.DataFrame
    skin: AnySkin
    about: Identity
    dpi: int
    page_dpi: int


@dataclass(frozen=True)
class FigureFiles:
    """What drawing one figure gives: its PNG and SVG files' bytes, and its rendering for
    the page."""

    png: bytes
    svg: bytes
    shown: Rendering


def draw_figure(job: FigureJob, key: str = "") -> FigureFiles:
    """Draw one figure: its PNG and SVG bytes, and its PNG for the page, with its width
    and smallest text (how wide the page shows it). ``key``: the figure's key
    (:func:`figure_key`), which only the figure cache reads."""
    import matplotlib.pyplot as plt

    from eskin.reporting import figures as fig

    figure = draw(job.spec, job.oof, job.skin)
    fig.identify(figure, job.about.heading)
    png, svg = save(figure, job.about, job.dpi)
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=job.page_dpi,
                   metadata={"Title": job.about.title, "Software": None})
    shown = Rendering(buffer.getvalue(), figure.get_figwidth(), fig.smallest_text(figure))
    plt.close(figure)
    return FigureFiles(png, svg, shown)


def drawing_code() -> str:
    """The version of what draws a figure, for the figure cache's keys: the sources of the
    drawers (``figures.py``), of this module (which calls them and saves the files) and of
    the skin's class, and the versions of matplotlib and numpy. The figure's data, its
    spec, its text and its skin are the cached call's arguments, so they are in the key
    already: a headline label edited in ``presentation.py`` redraws nothing."""
    package = Path(__file__).parent
    return _code_version(("matplotlib", "numpy"),
                         (package / "figures.py", Path(__file__), package.parent / "skin.py"))


def _code_version(distributions: Sequence[str], sources: Sequence[Path]) -> str:
    """The md5 of the ``distributions``' installed versions and the ``sources``' bytes."""
    digest = hashlib.md5(" ".join(version(name) for name in distributions).encode())
    for source in sources:
        digest.update(source.read_bytes())
    return digest.hexdigest()


def figure_key(job: FigureJob, code: str) -> str:
    """What decides a figure's files, by content: its predictions' values, columns and
    dtypes, its spec, skin, identity and resolutions, and the drawing code (``code``,
    :func:`drawing_code`). Not joblib's hash of the job: a frame of nullable columns
    pickled to a worker and back hashes differently there, so the parent could not tell
    which figures the cache holds."""
    digest = hashlib.md5(code.encode())
    digest.update(pd.util.hash_pandas_object(job.oof, index=False).to_numpy().tobytes())
    digest.update(repr([(str(c), str(t)) for c, t in job.oof.dtypes.items()]).encode())
    digest.update(joblib.hash((job.spec, job.skin, job.about, job.dpi, job.page_dpi)).encode())
    return digest.hexdigest()


# A cache holds the figures and scored pairs of this many reports (about 8 MB a report
# on the default scenes), the most recently used kept.
CACHE_REPORTS = 8


def _draw_all(jobs: list[FigureJob], memory: Memory | None = None) -> list[FigureFiles]:
    """Every figure, on as many cores as this process may use (at most two figures at a
    time): each figure is drawn on its own, so the files are the same in any order.
    Drawing was most of the report's time (12 figures × 3 files: about 9 of its 12 s).

    ``memory``: where each figure's files are kept under a key of its data, spec, skin,
    identity and drawing code (joblib's Memory): a figure whose key is there is read, not
    drawn again. An experiment that changes one model redraws only that model's figures;
    a report that draws none imports no matplotlib (issue 55: a headline label edited)."""
    draw_one: Callable[..., FigureFiles] = draw_figure
    keys = [""] * len(jobs)
    if memory is not None:
        draw_one = memory.cache(draw_figure, ignore=["job"])
        code = drawing_code()
        keys = [figure_key(job, code) for job in jobs]
    to_draw = sum(memory is None or not draw_one.check_call_in_cache(job, key)
                  for job, key in zip(jobs, keys, strict=True))
    if not to_draw:
        return [draw_one(job, key) for job, key in zip(jobs, keys, strict=True)]
    from eskin.reporting import figures  # noqa: F401 - once, before the workers fork
    workers = min(2, len(os.sched_getaffinity(0)), to_draw)
    if workers < 2:
        return [draw_one(job, key) for job, key in zip(jobs, keys, strict=True)]
    # fork: the workers start with matplotlib and the data already imported. The parent
    # has read Parquet; Arrow's thread pool and allocator register at-fork handlers (a
    # forked child of a threaded process is otherwise unsafe).
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork")) as pool:
        return list(pool.map(draw_one, jobs, keys))


def provenance(environ: Mapping[str, str] | None = None) -> Provenance:
    """Which run the report is: under ``dvc exp run``, the experiment's name and its
    baseline commit, as DVC gives them to each stage (``DVC_EXP_NAME``,
    ``DVC_EXP_BASELINE_REV``); under a plain ``dvc repro``, neither.

    A plain run names no commit, on purpose: the commit that records its dvc.lock does
    not exist yet, and naming the one checked out would make the page's bytes change
    with every commit while nothing it shows does (a fresh clone's ``make repro`` would
    then rewrite dvc.lock). The models' md5s on the page lead to their MLflow runs, which
    carry the commit."""
    environ = os.environ if environ is None else environ
    return Provenance(commit=environ.get("DVC_EXP_BASELINE_REV", ""),
                      experiment=environ.get("DVC_EXP_NAME", ""))


def scored_pairs(scene: str, predictions: Mapping[str, pd.DataFrame],
                 localise: Mapping[str, Any] | None, code: str = "") -> tuple[dict, bool]:
    """:func:`~eskin.evaluation.pairs.score_scene_pairs`'s document, and whether it
    applies (the scene has two contacts): plain data, so that reading it from the cache
    imports nothing. Imported here: scoring imports scikit-learn's metrics, which a report
    that scores nothing anew does without. ``code``: the version of the scoring code,
    which only the cache reads."""
    from eskin.evaluation.pairs import score_scene_pairs

    paired = score_scene_pairs(scene, predictions, localise)
    return paired.document, paired.applies


def pairs_code() -> str:
    """The version of the pairs' scoring code, for the cache's keys, as
    :func:`drawing_code` is the figures': the sources of ``pairs.py`` and of the eskin
    modules it imports (the scores, the kinds and their skins), and the versions of
    numpy, scipy and scikit-learn."""
    package = Path(__file__).parents[1]
    return _code_version(("numpy", "scipy", "scikit-learn"),
                         [package / source for source in ("evaluation/pairs.py",
                                                          "evaluation/metrics.py", "kinds.py",
                                                          "skin.py")])


# What a scene's contacts are scored as sets from: its tasks' predictions (pairs.py)
PAIRED_TASKS = ("localise", "force")


def _score_pairs(scores: dict[str, dict[str, Any]],
                 predictions: Mapping[str, Mapping[str, pd.DataFrame]],
                 pairs_dir: Path | None, scores_dir: Path, memory: Memory | None = None) -> None:
    """Each scene's contacts scored as sets, added to its scores (last, as ``pairs``) and
    written where the scene has two contacts (a one-contact scene's says why it has none,
    on the page, and has no file). A file left by a scene since removed is deleted. The
    directory is made even when no scene has two contacts: it is the publish stage's DVC
    output, which must exist. ``memory``: where each scene's scoring is kept under a key
    of its predictions, localise scores and scoring code, so that a scene whose
    predictions are unchanged is not scored again."""
    score: Callable[..., Any] = scored_pairs
    code = ""
    if memory is not None:
        score, code = memory.cache(scored_pairs), pairs_code()
    if pairs_dir is not None:
        pairs_dir.mkdir(parents=True, exist_ok=True)
        for stale in pairs_dir.glob("*.json"):
            if stale.stem not in scores:
                stale.unlink()
    for scene, by_task in scores.items():
        if "localise" not in by_task:  # nothing trained to pair
            continue
        document, applies = score(scene, {task: frame for task, frame
                                          in predictions[scene].items()
                                          if task in PAIRED_TASKS}, by_task["localise"], code)
        by_task[PAIRS] = document
        if applies:
            write_json(document, (pairs_dir / f"{scene}.json" if pairs_dir is not None
                                  else scores_dir / scene / f"{PAIRS}.json"))


def _task_files(directory: Path, scene: str, suffix: str, reader) -> dict[str, Any]:
    found = {}
    for task in TASK_NAMES:
        path = Path(directory) / scene / f"{task}{suffix}"
        if path.exists():
            found[task] = reader(path)
    return found


# What a `dvc plots` panel shows, by target (its title, with the scene's name); a node
# target's, or one contact's force, is :func:`panel_label`'s.
PANEL_LABEL = {"stretch": "stretch λ", "force": "force (N)", "contact": "contact",
               "contacts": "contacts pressing"}


def panel_label(target: str, skin: AnySkin) -> str:
    """A `dvc plots` panel's title: ``x terminal``, ``y position of contact 2``, ``force of
    contact 1 (N)``, …"""
    if target in PANEL_LABEL:
        return PANEL_LABEL[target]
    if target.startswith("force"):
        return f"force of contact {target.removeprefix('force')} (N)"
    axis, contact = target[0], target[1:]
    return f"{axis} {node_word(skin)}" + (f" of contact {contact}" if contact else "")


# Parity points a `dvc plots` panel draws at most (every k-th prediction beyond): with
# all 24,240 a panel, DVC's page was 28 MB and took Chromium 13 s to draw.
PLOT_POINTS = 4000


def plot_data(scene: str, kind: str, skin: AnySkin, predictions: dict[str, pd.DataFrame]
              ) -> list[tuple[str, str, pd.DataFrame]]:
    """(template, file stem, frame) behind `dvc plots` for one scene: parity data of every
    regression target (at most ``PLOT_POINTS``, evenly through the predictions), confusion
    counts of every class target, one CV scheme; a ``panel`` column names the scene and
    target (the templates title each panel with it)."""
    out = []
    for task, target in (("stretch", "stretch"), *(("force", t) for t in force_columns(kind))):
        frame = predictions.get(task)
        if frame is not None and not frame.empty:
            columns = {f"{target}_true": "actual", f"{target}_pred": "predicted"}
            if task == "force" and not get_kind(kind).several:
                columns["stretch"] = "stretch"
            points = frame[list(columns)].rename(columns=columns)
            step = -(-len(points) // PLOT_POINTS)
            out.append(("parity", target, points.iloc[::step].round(4)))
    for task, targets in (("detect", [get_kind(kind).detect_target]),
                          ("localise", node_columns(kind))):
        frame = predictions.get(task)
        if frame is not None and not frame.empty:
            for target in targets:
                classes = frame[[f"{target}_true", f"{target}_pred"]].rename(
                    columns={f"{target}_true": "actual", f"{target}_pred": "predicted"})
                if target == "contact":
                    classes = classes.apply(lambda c: c.map({True: "contact", False: "none"}))
                out.append(("confusion", target, classes.value_counts().rename("count")
                            .reset_index().sort_values(["actual", "predicted"])))
    return [(template, stem, frame.assign(panel=f"{scene}: {panel_label(stem, skin)}"))
            for template, stem, frame in out]


@dataclass(frozen=True)
class Reported:
    """What :func:`report` wrote: ``figures`` figures (PNG + SVG) of the ``kinds`` of
    scenes, plot data, the page and the results tables."""

    kinds: dict[str, str]
    figures: int
    figures_dir: Path
    plots_dir: Path
    page_path: Path
    results_path: Path
    summary: str


def report(*, report: Report, scenes: Mapping[str, Scene], scores_dir: Path,
           predictions_dir: Path, figures_dir: Path, plots_dir: Path, page_path: Path,
           results_path: Path, metrics_path: Path, scene_metrics_dir: Path | None = None,
           run: Provenance | None = None,
           model_runs: Callable[[str], str] | None = None,
           cache: Path | None = None, pairs_dir: Path | None = None) -> Reported:
    """Figures, plot data, the page, the results and DVC's metrics of every scene in
    ``scenes`` (the ``scenes`` section: which, and their kinds), with the ``report``
    section; ``run``: which commit and experiment the page says it shows
    (:func:`provenance`); ``scene_metrics_dir``: where DVC's metrics go, a file a scene
    (:func:`scene_metrics`); ``model_runs``: a model md5 → the MLflow UI's page of its
    runs, the page's link; ``cache``: where drawn figures and scored pairs are kept, so
    that an unchanged figure is not drawn again (:func:`_draw_all`) nor an unchanged
    scene's pairs scored again (:func:`_score_pairs`; None: all drawn and scored);
    ``pairs_dir``: where a two-contact scene's contacts scored as sets are written, a file
    a scene (:func:`~eskin.evaluation.pairs.score_scene_pairs`; None: ``scores_dir``/
    ``<scene>``/pairs.json, a direct run's layout)."""
    settings = report
    kinds = {name: scene_kind(scene).name for name, scene in scenes.items()}
    skins = {name: scene_skin(scene) for name, scene in scenes.items()}
    scores = {scene: _task_files(scores_dir, scene, ".json", lambda p: json.loads(p.read_text()))
              for scene in kinds}
    if not any(scores.values()):
        raise FileNotFoundError(f"{scores_dir}: no scores for any scene of params.yaml "
                                f"({', '.join(kinds)}); run the training stages first")
    predictions = {scene: _task_files(predictions_dir, scene, ".parquet", pd.read_parquet)
                   for scene in kinds}
    memory = Memory(cache, verbose=0) if cache is not None else None
    # scored from the predictions just read, not read again
    _score_pairs(scores, predictions, Path(pairs_dir) if pairs_dir is not None else None,
                 Path(scores_dir), memory)

    figures_dir, plots_dir = Path(figures_dir), Path(plots_dir)
    # The directories hold this run's figures and plot data only: none left from a scene,
    # figure or scheme since removed or renamed (their DVC outputs persist).
    for stale in [*figures_dir.glob("*/*.png"), *figures_dir.glob("*/*.svg"),
                  *plots_dir.glob("*/*.csv")]:
        stale.unlink()
    page_figures: dict[str, list[FigureRow]] = {scene: [] for scene in kinds}
    jobs: list[tuple[FigureRow, str, Path, FigureJob]] = []
    for scene, kind in kinds.items():
        # each figure under every scheme, side by side on the page
        for spec in presentation.figures(get_kind(kind)):
            frame = predictions[scene].get(spec.task)
            if frame is None or frame.empty:
                continue
            row = FigureRow(id=f"{scene}-{spec.id}", file=spec.id, title=spec.title,
                            caption=spec.caption)
            page_figures[scene].append(row)
            for scheme in settings.schemes:
                oof = frame[frame["scheme"] == scheme]
                if oof.empty:  # a scheme the scene's data did not allow (trials: repeats 1)
                    continue
                about = identity(scene, spec, scheme, oof, scores[scene].get(spec.task))
                (figures_dir / scene).mkdir(parents=True, exist_ok=True)
                jobs.append((row, scheme, figures_dir / scene / f"{spec.id}_{scheme}",
                             FigureJob(spec, oof, skins[scene], about, int(settings.dpi),
                                       int(settings.page_dpi))))
        chosen = {task: frame[frame["scheme"] == settings.plots_scheme]
                  for task, frame in predictions[scene].items() if not frame.empty}
        for template, stem, frame in plot_data(scene, kind, skins[scene], chosen):
            (plots_dir / template).mkdir(parents=True, exist_ok=True)
            frame.to_csv(plots_dir / template / f"{scene}_{stem}.csv", index=False)
    for (row, scheme, path, job), files in zip(jobs, _draw_all([job for *_, job in jobs],
                                                               memory), strict=True):
        path.with_suffix(".png").write_bytes(files.png)
        path.with_suffix(".svg").write_bytes(files.svg)
        row.schemes.append((scheme, job.about.heading.replace("\n", "; "), files.shown))
    if memory is not None:
        memory.reduce_size(items_limit=CACHE_REPORTS * max(len(jobs) + len(kinds), 1))

    scenes = [(scene, kinds[scene], skins[scene], scores[scene]) for scene in kinds]
    href = Path(os.path.relpath(figures_dir, Path(page_path).parent)).as_posix()
    Path(page_path).write_text(render_page(scenes, page_figures, run or Provenance(), href,
                                           model_runs))
    Path(results_path).write_text(results_markdown(scenes))
    Path(metrics_path).write_text(json.dumps(headline_metrics(scores), indent=2) + "\n")
    if scene_metrics_dir is not None:
        scene_metrics_dir = Path(scene_metrics_dir)
        scene_metrics_dir.mkdir(parents=True, exist_ok=True)
        for stale in scene_metrics_dir.glob("*.json"):  # a scene since removed
            stale.unlink()
        for scene in kinds:
            numbers = scene_metrics(scores[scene])
            if numbers:
                (scene_metrics_dir / f"{scene}.json").write_text(
                    json.dumps(numbers, indent=2) + "\n")
    return Reported(kinds, len(jobs), figures_dir, plots_dir, Path(page_path), Path(results_path),
                    f"report: {len(kinds)} scene(s), {len(jobs)} figures (PNG + SVG) in "
                    f"{figures_dir}, plot data in {plots_dir}, {page_path}, results in "
                    f"{results_path}, headline scores in {metrics_path}")



def headline_metrics(scores: Mapping[str, Mapping[str, dict]]) -> dict[str, dict]:
    """DVC's metrics, one table for every scene: each scored task's headline scores under
    the headline scheme (``<scene>.<task>.<target>.<score>``, the target left out where
    it is the task: ``single_force.force.r2``; a pairs score sits under its task).
    ``scores``: every scene's scores files by task. A skipped task has no entry."""
    from eskin.evaluation.tasks import get_task

    metrics: dict[str, dict] = {}
    for scene, by_task in scores.items():
        for task_name, doc in by_task.items():
            scheme = doc.get(HEADLINE_SCHEME)
            if doc.get("status") not in ("trained", "scored") or not scheme:
                continue
            if task_name == PAIRS:
                entry = {name: scheme[name] for name in PAIRS_HEADLINE if name in scheme}
            else:
                task = get_task(doc["kind"], task_name)
                entry = {}
                for target in task.targets:
                    score = {task.headline_metric: scheme[target][task.headline_metric]}
                    entry.update(score if target == task_name else {target: score})
            metrics.setdefault(scene, {})[task_name] = entry
    return metrics


# DVC's name for a two-contact scene's scores as a set (eskin/evaluation/pairs.py).
SCENE_PAIRS_METRICS = {"pair_accuracy": "pairs", "force_r2": "pair_force"}


def scene_metrics(by_task: Mapping[str, dict]) -> dict[str, float]:
    """DVC's metrics of one scene: one number a question, under the headline scheme, named
    by its target (``stretch``, ``force``, ``contact``, ``x``, ``y``: R² for a regression,
    accuracy otherwise). Where the scene's contacts are scored as a set (``pairs``: both
    placed right; ``pair_force``: their forces' R²), those stand for each contact's own
    targets (``x1`` … ``force2``), which the full headline (``metrics.json``) keeps."""
    from eskin.evaluation.tasks import get_task

    pairs = by_task.get(PAIRS, {})
    as_set = pairs.get("status") == "scored" and bool(pairs.get(HEADLINE_SCHEME))
    out: dict[str, float] = {}
    for task_name, doc in by_task.items():
        scheme = doc.get(HEADLINE_SCHEME)
        if doc.get("status") not in ("trained", "scored") or not scheme:
            continue
        if task_name == PAIRS:
            out.update({name: scheme[score] for score, name in SCENE_PAIRS_METRICS.items()
                        if score in scheme})
            continue
        task, labelled = get_task(doc["kind"], task_name), get_kind(doc["kind"])
        # each contact's own position and force (not a total force): the set stands for them
        per_contact = {*labelled.node_columns,
                       *([] if labelled.total_force else labelled.force_columns)}
        for target in task.targets:
            if not (as_set and labelled.several and target in per_contact):
                out[target] = scheme[target][task.headline_metric]
    return out
