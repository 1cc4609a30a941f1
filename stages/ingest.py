"""DVC stage: data/raw/<scene>/ → data/processed/<scene>.parquet (+ quarantine CSV)."""

import sys

from eskin import steps
from eskin.cli import PROCESSED_DIR, RAW_DIR, run_friendly
from eskin.config import load_params

if __name__ == "__main__":
    scene = sys.argv[1]
    sys.exit(run_friendly(
        lambda: print(steps.ingest(load_params(), scene, RAW_DIR / scene, PROCESSED_DIR))))
