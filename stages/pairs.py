"""DVC stage: a two-force scene's predictions → order-free pair scores (and their headline)."""

import sys

from eskin.catalog import PAIRS, PREDICTIONS_DIR, metrics_path, scores_path
from eskin.config import get_scene, load_params
from eskin.errors import run_friendly
from eskin.learning import train


def main(scene: str) -> str:
    # The params only go to the MLflow pipeline run: the stage reads none of them.
    params = load_params()
    get_scene(params, scene)
    return train.score_pairs(scene, PREDICTIONS_DIR, metrics_path(scene, PAIRS),
                             scores_path(scene, PAIRS), pipeline_params=params).summary


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(sys.argv[1]))))
