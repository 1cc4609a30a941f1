"""DVC stage: a two-force scene's predictions → order-free pair scores (and their headline)."""

import sys

from eskin.catalog import PAIRS, PREDICTIONS_DIR, metrics_path, scores_path
from eskin.config import DEFAULT_PARAMS
from eskin.errors import run_friendly
from eskin.learning import train

if __name__ == "__main__":
    scene = sys.argv[1]
    sys.exit(run_friendly(lambda: print(train.score_pairs(
        scene, PREDICTIONS_DIR, metrics_path(scene, PAIRS), scores_path(scene, PAIRS),
        params_text=DEFAULT_PARAMS.read_text()))))
