"""DVC stage of `make stress`: the numerical stress suite (harness/stress.py)."""

import sys
import tempfile

from eskin.catalog import FEATURES_DIR
from eskin.config import load_params
from eskin.errors import run_friendly
from harness import stress

if __name__ == "__main__":
    with tempfile.TemporaryDirectory(prefix="eskin-stress-") as scratch:
        sys.exit(run_friendly(lambda: print(stress.stress(
            load_params(), FEATURES_DIR / "single_force.parquet", "reports/stress.json",
            "reports/stress.md", "reports/stress.html", scratch=scratch))))
