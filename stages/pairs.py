"""DVC stage: a two-force scene's predictions → order-free pair scores (metrics + MLflow)."""

import sys

from eskin import learn
from eskin.catalog import METRICS_DIR, PREDICTIONS_DIR
from eskin.config import DEFAULT_PARAMS
from eskin.errors import run_friendly

if __name__ == "__main__":
    scene = sys.argv[1]
    sys.exit(run_friendly(lambda: print(learn.score_pairs(
        scene, PREDICTIONS_DIR, METRICS_DIR / scene / "pairs.json",
        params_text=DEFAULT_PARAMS.read_text()))))
