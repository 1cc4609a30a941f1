"""Pipeline step of reporting: figures, DVC plot data, the report page, the README table.

Reads only the training stages' predictions and metrics, and its own
params (``report:``), so a change of figure style reruns only this step.
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import pandas as pd

from eskin.config import section
from eskin.reporting import figures as fig
from eskin.reporting.page import readme_section, render_page, replace_readme_results

TASKS = {"single_force": ("stretch", "force", "detect", "localise"),
         "two_force": ("force1", "force2", "localise", "pairs")}


def _load(directory: Path, suffix: str, reader) -> dict[tuple[str, str], Any]:
    found = {}
    for scene, tasks in TASKS.items():
        for task in tasks:
            path = Path(directory) / scene / f"{task}{suffix}"
            if path.exists():
                found[(scene, task)] = reader(path)
    return found


def _figures(predictions: dict, scheme: str) -> list[tuple[str, str, Any]]:
    """(id, caption, Figure) for every figure the predictions allow."""
    def rows(scene: str, task: str) -> pd.DataFrame | None:
        frame = predictions.get((scene, task))
        if frame is None or frame.empty:
            return None
        return frame[frame["scheme"] == scheme]

    out = []
    if (oof := rows("single_force", "stretch")) is not None:
        out.append(("stretch_parity", "Stretch: predicted against true λ, mean ± std per level "
                    "(paper Fig. 5)", fig.stretch_parity(oof)))
    if (oof := rows("single_force", "force")) is not None:
        out.append(("force_parity", "Force: predicted against true force, mean ± std per level "
                    "and stretch (paper Fig. 6)", fig.force_parity(oof)))
    if (oof := rows("single_force", "localise")) is not None:
        out.append(("localisation_confusion", "Localisation of a single contact: rows (x) and "
                    "columns (y); counts, colour normalised per true row (paper Fig. 7)",
                    fig.confusion_grid(oof, ["x", "y"], ["x terminal", "y terminal"])))
    if (oof := rows("single_force", "detect")) is not None:
        out.append(("detection", "Contact detection: confusion matrix and ROC curve",
                    fig.detection(oof)))
    if (oof := rows("two_force", "localise")) is not None:
        out.append(("two_force_localisation", "Two contacts: x and y of contact 1 (top) and "
                    "contact 2 (bottom) (paper Fig. 8)",
                    fig.confusion_grid(oof, ["x1", "y1", "x2", "y2"],
                                       ["x1 terminal", "y1 terminal", "x2 terminal",
                                        "y2 terminal"])))
    force1, force2 = rows("two_force", "force1"), rows("two_force", "force2")
    if force1 is not None and force2 is not None:
        out.append(("two_force_parity", "Two contacts: force of contact 1 and contact 2, "
                    "mean ± std per level (paper Fig. 9)", fig.two_force_parity(force1, force2)))
    return out


# Data behind `dvc plots`: (file, scene, task, columns to keep, renames).
PLOT_DATA = (
    ("stretch_parity.csv", "single_force", "stretch", {"stretch_true": "actual",
                                                        "stretch_pred": "predicted"}),
    ("force_parity.csv", "single_force", "force", {"force_true": "actual",
                                                    "force_pred": "predicted",
                                                    "stretch": "stretch"}),
    ("detection_confusion.csv", "single_force", "detect", {"contact_true": "actual",
                                                            "contact_pred": "predicted"}),
    *((f"localisation_{t}.csv", "single_force", "localise", {f"{t}_true": "actual",
                                                             f"{t}_pred": "predicted"})
      for t in ("x", "y")),
    *((f"two_force_{t}.csv", "two_force", "localise", {f"{t}_true": "actual",
                                                       f"{t}_pred": "predicted"})
      for t in ("x1", "y1", "x2", "y2")),
    *((f"two_force_{t}_parity.csv", "two_force", t, {f"{t}_true": "actual",
                                                      f"{t}_pred": "predicted"})
      for t in ("force1", "force2")),
)


def report(params: dict[str, Any], *, metrics_dir: Path, predictions_dir: Path,
           figures_dir: Path, plots_dir: Path, page_path: Path, readme_path: Path) -> str:
    settings = section(params, "report")
    metrics = _load(metrics_dir, ".json", lambda p: json.loads(p.read_text()))
    predictions = _load(predictions_dir, ".parquet", pd.read_parquet)
    if not metrics:
        raise FileNotFoundError(f"{metrics_dir}: no metrics; run the training stages first")

    figures_dir, plots_dir = Path(figures_dir), Path(plots_dir)
    figures_dir.mkdir(parents=True, exist_ok=True)
    plots_dir.mkdir(parents=True, exist_ok=True)
    page_figures, written = [], 0
    for scheme in settings["schemes"]:
        for fid, caption, figure in _figures(predictions, scheme):
            name = f"{fid}_{scheme}"
            for fmt in ("png", "svg"):
                figure.savefig(figures_dir / f"{name}.{fmt}", dpi=int(settings["dpi"]),
                               metadata={"Date": None} if fmt == "svg" else {"Software": None})
            buffer = io.BytesIO()
            figure.savefig(buffer, format="png", dpi=int(settings["page_dpi"]))
            plt.close(figure)
            page_figures.append((name, f"{caption} — {scheme} CV.", buffer.getvalue()))
            written += 1

    for filename, scene, task, columns in PLOT_DATA:
        frame = predictions.get((scene, task))
        if frame is None or frame.empty:
            continue
        chosen = frame[frame["scheme"] == settings["plots_scheme"]]
        chosen[list(columns)].rename(columns=columns).to_csv(plots_dir / filename, index=False)

    Path(page_path).write_text(render_page(metrics, page_figures))
    readme = Path(readme_path)
    readme.write_text(replace_readme_results(readme.read_text(), readme_section(metrics)))
    return (f"report: {written} figures (PNG + SVG) in {figures_dir}, plot data in {plots_dir}, "
            f"{page_path}, results table in {readme_path}")
