"""DVC stage: data/processed/<scene>.parquet → data/features/<scene>.parquet + fitted transform."""

import sys

from eskin.catalog import FEATURES_DIR, MODELS_DIR, PROCESSED_DIR
from eskin.config import load_params
from eskin.errors import run_friendly
from eskin.learning.features import featurize_scene

if __name__ == "__main__":
    scene = sys.argv[1]
    sys.exit(run_friendly(lambda: print(
        featurize_scene(load_params(), scene, PROCESSED_DIR, FEATURES_DIR, MODELS_DIR))))
