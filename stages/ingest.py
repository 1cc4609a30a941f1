"""DVC stage: data/raw/<scene>/ → data/processed/<scene>.parquet (+ quarantine CSV)."""

import sys

from eskin.catalog import PROCESSED_DIR, RAW_DIR
from eskin.config import load_params
from eskin.data import build
from eskin.errors import run_friendly

if __name__ == "__main__":
    scene = sys.argv[1]
    sys.exit(run_friendly(
        lambda: print(build.ingest(load_params(), scene, RAW_DIR / scene, PROCESSED_DIR))))
