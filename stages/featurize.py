"""DVC stage: data/processed/<scene>.parquet → data/features/<scene>.parquet + fitted
transform."""

import sys

from eskin.errors import run_friendly
from eskin.steps.featurize import run as main

if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(sys.argv[1]))))
