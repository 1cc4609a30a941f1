"""DVC stage: a two-force scene's predictions → order-free pair scores."""

import sys

from eskin.catalog import PAIRS, PREDICTIONS_DIR, scores_path
from eskin.config.base import load_params, sections
from eskin.config.scenes import Scenes, get_scene
from eskin.errors import run_friendly
from eskin.evaluation.pairs import score_scene_pairs


def main(scene: str) -> str:
    get_scene(load_params(sections(scenes=Scenes)), scene)
    return score_scene_pairs(scene, PREDICTIONS_DIR, scores_path(scene, PAIRS)).summary


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(sys.argv[1]))))
