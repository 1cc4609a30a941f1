"""Pipeline step of reporting: figures, DVC plot data, the report page, the results page.

Reads only the training stages' predictions and scores, the scene list
(``scenes:``, names and kinds) and its own params (``report:``), so a change
of figure style reruns only this step. Every scene gets its own figures,
plot data and section; what a figure shows follows the scene's kind.
"""

from __future__ import annotations

import io
import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import pandas as pd

from eskin.catalog import SCORED_TASKS
from eskin.config import Report, Scene
from eskin.data.schema import force_columns, node_columns
from eskin.kinds import Figure, get_kind
from eskin.reporting import figures as fig
from eskin.reporting.page import render_page, results_markdown


def draw(figure: Figure, oof: pd.DataFrame):
    """One of a kind's figures (eskin/kinds.py) from its task's out-of-fold predictions."""
    build = getattr(fig, figure.draw)
    if figure.targets:
        return build(oof, list(figure.targets), list(figure.axis_labels), title=figure.title)
    return build(oof)


def _task_files(directory: Path, scene: str, suffix: str, reader) -> dict[str, Any]:
    found = {}
    for task in SCORED_TASKS:
        path = Path(directory) / scene / f"{task}{suffix}"
        if path.exists():
            found[task] = reader(path)
    return found


# What a `dvc plots` panel shows, by target (its title, with the scene's name).
PANEL_LABEL = {"stretch": "stretch λ", "force": "force (N)", "force1": "force of contact 1 (N)",
               "force2": "force of contact 2 (N)", "contact": "contact",
               "x": "x terminal", "y": "y terminal", "x1": "x terminal of contact 1",
               "y1": "y terminal of contact 1", "x2": "x terminal of contact 2",
               "y2": "y terminal of contact 2"}


# Parity points a `dvc plots` panel draws at most (every k-th prediction beyond): with
# all 24,240 a panel, DVC's page was 28 MB and took Chromium 13 s to draw.
PLOT_POINTS = 4000


def plot_data(scene: str, kind: str, predictions: dict[str, pd.DataFrame]
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
            if task == "force" and get_kind(kind).contacts == 1:
                columns["stretch"] = "stretch"
            points = frame[list(columns)].rename(columns=columns)
            step = -(-len(points) // PLOT_POINTS)
            out.append(("parity", target, points.iloc[::step].round(4)))
    for task, targets in (("detect", ["contact"]), ("localise", node_columns(kind))):
        frame = predictions.get(task)
        if frame is not None and not frame.empty:
            for target in targets:
                classes = frame[[f"{target}_true", f"{target}_pred"]].rename(
                    columns={f"{target}_true": "actual", f"{target}_pred": "predicted"})
                if target == "contact":
                    classes = classes.apply(lambda c: c.map({True: "contact", False: "none"}))
                out.append(("confusion", target, classes.value_counts().rename("count")
                            .reset_index().sort_values(["actual", "predicted"])))
    return [(template, stem, frame.assign(panel=f"{scene}: {PANEL_LABEL[stem]}"))
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
           results_path: Path) -> Reported:
    """Figures, plot data, the page and the results of every scene in ``scenes`` (the
    ``scenes`` section: which, and their kinds), with the ``report`` section."""
    settings = report
    kinds = {name: scene.kind for name, scene in scenes.items()}
    scores = {scene: _task_files(scores_dir, scene, ".json", lambda p: json.loads(p.read_text()))
              for scene in kinds}
    if not any(scores.values()):
        raise FileNotFoundError(f"{scores_dir}: no scores for any scene of params.yaml "
                                f"({', '.join(kinds)}); run the training stages first")
    predictions = {scene: _task_files(predictions_dir, scene, ".parquet", pd.read_parquet)
                   for scene in kinds}

    figures_dir, plots_dir = Path(figures_dir), Path(plots_dir)
    page_figures: dict[str, list[tuple[str, str, bytes]]] = {scene: [] for scene in kinds}
    written = 0
    for scene, kind in kinds.items():
        # each figure under every scheme, one after the other on the page
        for spec in get_kind(kind).figures:
            frame = predictions[scene].get(spec.task)
            if frame is None or frame.empty:
                continue
            for scheme in settings.schemes:
                figure = draw(spec, frame[frame["scheme"] == scheme])
                name = f"{spec.id}_{scheme}"
                (figures_dir / scene).mkdir(parents=True, exist_ok=True)
                for fmt in ("png", "svg"):
                    figure.savefig(figures_dir / scene / f"{name}.{fmt}", dpi=int(settings.dpi),
                                   metadata={"Date": None} if fmt == "svg" else {"Software": None})
                buffer = io.BytesIO()
                figure.savefig(buffer, format="png", dpi=int(settings.page_dpi))
                plt.close(figure)
                page_figures[scene].append((f"{scene}-{name}", f"{spec.caption} — {scheme} CV.",
                                            buffer.getvalue()))
                written += 1
        chosen = {task: frame[frame["scheme"] == settings.plots_scheme]
                  for task, frame in predictions[scene].items() if not frame.empty}
        for template, stem, frame in plot_data(scene, kind, chosen):
            (plots_dir / template).mkdir(parents=True, exist_ok=True)
            frame.to_csv(plots_dir / template / f"{scene}_{stem}.csv", index=False)

    scenes = [(scene, kinds[scene], scores[scene]) for scene in kinds]
    Path(page_path).write_text(render_page(scenes, page_figures))
    Path(results_path).write_text(results_markdown(scenes))
    return Reported(kinds, written, figures_dir, plots_dir, Path(page_path), Path(results_path),
                    f"report: {len(kinds)} scene(s), {written} figures (PNG + SVG) in "
                    f"{figures_dir}, plot data in {plots_dir}, {page_path}, results in "
                    f"{results_path}")

