"""DVC stage: a two-force scene's predictions → order-free pair scores."""

import sys

from eskin.catalog import PAIRS, PREDICTIONS_DIR, scores_path
from eskin.config import get_scene, load_params
from eskin.errors import run_friendly
from eskin.learning import train


def main(scene: str) -> str:
    get_scene(load_params(), scene)
    return train.score_pairs(scene, PREDICTIONS_DIR, scores_path(scene, PAIRS)).summary


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(sys.argv[1]))))
