"""DVC stage: predictions + scores → figures, plot data, reports/index.html, reports/results.md;
the figures and the page go to the pipeline's MLflow run as artifacts."""

import sys

from eskin.catalog import FIGURES_DIR, PAGE, PLOTS_DIR, PREDICTIONS_DIR, SCORES_DIR
from eskin.config import load_params
from eskin.errors import run_friendly
from eskin.reporting import report


def main() -> str:
    params = load_params()
    result = report.report(
        report=params.report, scenes=params.scenes, scores_dir=SCORES_DIR,
        predictions_dir=PREDICTIONS_DIR, figures_dir=FIGURES_DIR, plots_dir=PLOTS_DIR,
        page_path=PAGE, results_path="reports/results.md", run=report.provenance())
    from eskin.tracking import runs  # MLflow takes seconds to import

    page = runs.log_report(figures_dir=FIGURES_DIR, page_path=PAGE, pipeline_params=params)
    return f"{result.summary}\nfigures and page in MLflow: {page}"


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main())))
