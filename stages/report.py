"""DVC stage: predictions + scores → a two-contact scene's contacts scored as sets
(reports/pairs/), figures, plot data, reports/index.html, reports/results.md, the headline
scores (reports/metrics.json) and DVC's metrics, a file a scene (reports/metrics/)."""

import functools
import sys

from eskin.catalog import (
    FIGURE_CACHE,
    FIGURES_DIR,
    METRICS,
    PAGE,
    PAIRS_DIR,
    PLOTS_DIR,
    PREDICTIONS_DIR,
    SCENE_METRICS_DIR,
    SCORES_DIR,
)
from eskin.config.base import load_params, sections
from eskin.config.report import Report
from eskin.config.scenes import Scenes
from eskin.errors import run_friendly
from eskin.reporting import report
from eskin.tracking import connection


def main() -> str:
    params = load_params(sections(report=Report, scenes=Scenes))
    # The page links each model to its runs in MLflow's UI, which are logged later (the
    # tracking stage): by the experiment the tracking stage logs to, found or made here.
    # A store out of reach costs the links, not the report.
    try:
        model_runs = functools.partial(connection.model_runs_url, connection.ensure_experiment())
    except connection.TrackingError as err:
        print(f"report: the page's model md5s link nowhere: {err}", file=sys.stderr)
        model_runs = None
    return report.report(
        report=params.report, scenes=params.scenes, scores_dir=SCORES_DIR,
        predictions_dir=PREDICTIONS_DIR, figures_dir=FIGURES_DIR, plots_dir=PLOTS_DIR,
        page_path=PAGE, results_path="reports/results.md", metrics_path=METRICS,
        scene_metrics_dir=SCENE_METRICS_DIR, run=report.provenance(),
        model_runs=model_runs, figure_cache=FIGURE_CACHE,
        pairs_dir=PAIRS_DIR).summary


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main())))
