"""DVC stage: data/processed/<scene>.parquet → data/features/<scene>.parquet + fitted transform."""

import sys

from eskin.catalog import FEATURES_DIR, MODELS_DIR, PROCESSED_DIR
from eskin.config.base import load_params, sections
from eskin.config.featurize import Featurize
from eskin.config.scenes import Scenes, get_scene
from eskin.errors import run_friendly
from eskin.learning.features import featurize_scene


def main(scene: str) -> str:
    params = load_params(sections(scenes=Scenes, featurize=Featurize))
    get_scene(params, scene)
    return featurize_scene(scene, PROCESSED_DIR, FEATURES_DIR, MODELS_DIR,
                           settings=params.featurize).summary


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(sys.argv[1]))))
