"""DVC stage: predictions + metrics → figures, plot data, reports/index.html, reports/results.md."""

import sys

from eskin import report
from eskin.catalog import METRICS_DIR, PREDICTIONS_DIR
from eskin.config import load_params
from eskin.errors import run_friendly

if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(report.report(
        load_params(), metrics_dir=METRICS_DIR, predictions_dir=PREDICTIONS_DIR,
        figures_dir="reports/figures", plots_dir="reports/plots",
        page_path="reports/index.html", results_path="reports/results.md"))))
