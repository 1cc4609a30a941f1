"""DVC stage of `make bench`: the soak (harness/soak.py) on the whole single-force scene."""

import json
import sys
import tempfile
from pathlib import Path

import pandas as pd

from eskin.catalog import PROCESSED_DIR
from eskin.config import load_params, section
from eskin.errors import run_friendly
from harness.soak import run_soak

REPORT = Path("reports/soak")


def main() -> str:
    params = load_params()
    settings = section(params, "soak")
    # The clean run of the same seed: the pipeline's own acquisition.
    reference = pd.read_parquet(PROCESSED_DIR / "single_force.parquet")
    with tempfile.TemporaryDirectory(prefix="eskin-soak-") as scratch:
        result = run_soak(params, settings, Path(scratch), reference,
                          kill_at=settings["kill_at"])
    REPORT.mkdir(parents=True, exist_ok=True)
    (REPORT / "soak.json").write_text(json.dumps(result.as_dict(), indent=2) + "\n")
    (REPORT / "soak.md").write_text(result.markdown())
    print(result.markdown())
    return 0 if result.passed else 1


if __name__ == "__main__":
    sys.exit(run_friendly(main))
