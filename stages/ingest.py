"""DVC stage: data/raw/<scene>/ → data/processed/<scene>.parquet (+ quarantine CSV)."""

import sys

from eskin.errors import run_friendly
from eskin.steps.ingest import run as main

if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(sys.argv[1]))))
