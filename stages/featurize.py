"""DVC stage: data/processed/<scene>.parquet → data/features/<scene>.parquet + fitted transform."""

import sys

from eskin import learn
from eskin.cli import FEATURES_DIR, MODELS_DIR, PROCESSED_DIR, run_friendly
from eskin.config import load_params

if __name__ == "__main__":
    scene = sys.argv[1]
    sys.exit(run_friendly(lambda: print(
        learn.featurize(load_params(), scene, PROCESSED_DIR, FEATURES_DIR, MODELS_DIR))))
