"""DVC stage: acquire one scene into data/raw/<scene>/ (resumes; reuses what is recorded)."""

import sys

from eskin.acquisition import acquire
from eskin.catalog import RAW_DIR
from eskin.config import load_params
from eskin.errors import run_friendly

if __name__ == "__main__":
    scene = sys.argv[1]
    sys.exit(run_friendly(lambda: print(acquire.acquire(load_params(), scene, RAW_DIR / scene))))
