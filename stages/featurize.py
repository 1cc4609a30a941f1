"""DVC stage: data/processed/<scene>.parquet → data/features/<scene>.parquet + fitted transform."""

import sys

from eskin.catalog import FEATURES_DIR, MODELS_DIR, PROCESSED_DIR
from eskin.config import get_scene, load_params
from eskin.errors import run_friendly
from eskin.learning.features import featurize_scene


def main(scene: str) -> str:
    params = load_params()
    get_scene(params, scene)
    return featurize_scene(scene, PROCESSED_DIR, FEATURES_DIR, MODELS_DIR,
                           settings=params.featurize).summary


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(sys.argv[1]))))
