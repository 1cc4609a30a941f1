"""DVC stage: data/features/<scene>.parquet → data/folds/<scene>.parquet, every CV scheme's
folds drawn once, so that no training stage draws them again."""

import sys

from eskin.errors import run_friendly
from eskin.steps.folds import run as main

if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(sys.argv[1]))))
