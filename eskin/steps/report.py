"""The report of the pipeline's scenes (:func:`eskin.reporting.report.report`), kept when
written from the same predictions, scores, params, run and code.

The publish stage writes the report, then logs to MLflow. A rerun that changes nothing
the report shows (a tracking code edit, the runs logged again to another store) keeps
it as it is, as the tracking stage left it before the two were one stage: its inputs
and outputs are recorded by md5 in ``.cache/report.json``. The page's links to the
runs are not among its inputs: they name the store the page was written against."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from eskin.catalog import (
    FIGURE_CACHE,
    FIGURES_DIR,
    METRICS,
    PAGE,
    PAIRS_DIR,
    PLOTS_DIR,
    PREDICTIONS_DIR,
    REPORT_CACHE,
    SCENE_METRICS_DIR,
    SCORES_DIR,
)
from eskin.config.params import Params
from eskin.reporting import report
from eskin.steps import code
from eskin.steps.keep import kept, tree_md5, write_record

RESULTS = Path("reports/results.md")
OUTPUTS = (FIGURES_DIR, PLOTS_DIR, PAIRS_DIR, PAGE, RESULTS, METRICS, SCENE_METRICS_DIR)
TEMPLATES = Path(report.__file__).parent / "templates"


def report_at(params: Params, model_runs: Callable[[], Callable[[str], str] | None],
              root: Path = Path(".")) -> str:
    """The report's summary; ``model_runs`` is asked for the page's links only when the
    report is written."""
    root = Path(root)
    run = report.provenance()
    inputs = {"predictions_md5": tree_md5(root / PREDICTIONS_DIR),
              "scores_md5": tree_md5(root / SCORES_DIR),
              "params": {"report": params.report.model_dump(mode="json"),
                         "scenes": {name: scene.model_dump(mode="json")
                                    for name, scene in params.scenes.items()}},
              "run": {"commit": run.commit, "experiment": run.experiment},
              "code_md5": code.code_md5(report.__file__), "templates_md5": tree_md5(TEMPLATES)}
    record = root / REPORT_CACHE
    if kept(root, record, inputs, OUTPUTS):
        return "report: kept, written from these predictions, scores, params and code"
    summary = report.report(
        report=params.report, scenes=params.scenes, scores_dir=root / SCORES_DIR,
        predictions_dir=root / PREDICTIONS_DIR, figures_dir=root / FIGURES_DIR,
        plots_dir=root / PLOTS_DIR, page_path=root / PAGE, results_path=root / RESULTS,
        metrics_path=root / METRICS, scene_metrics_dir=root / SCENE_METRICS_DIR, run=run,
        model_runs=model_runs(), cache=root / FIGURE_CACHE,
        pairs_dir=root / PAIRS_DIR).summary
    write_record(root, record, inputs, OUTPUTS)
    return summary
