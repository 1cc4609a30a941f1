"""DVC stage of `make bench`: the soak (harness/soak.py) of one simulated scene."""

import json
import sys
import tempfile
from pathlib import Path

import pandas as pd

from eskin.catalog import SOAK_DIR, processed_path
from eskin.config.base import BENCH_PARAMS, load_params, sections
from eskin.config.params import Params
from eskin.config.scenes import get_scene
from eskin.errors import run_friendly
from harness.params import Soak
from harness.soak import run_soak


def main(scene: str) -> int:
    params = load_params(Params)
    get_scene(params, scene)
    settings = load_params(sections(BENCH_PARAMS, soak=Soak)).soak
    SOAK_DIR.mkdir(parents=True, exist_ok=True)
    json_path, md_path = SOAK_DIR / f"{scene}.json", SOAK_DIR / f"{scene}.md"
    source = params.scenes[scene].source
    if source != "simulated":
        # The soak compares with a clean run of the same seed: only the simulator has one.
        reason = f"a soak needs the simulated board; this scene's data comes from {source}"
        json_path.write_text(json.dumps({"scene": scene, "status": "skipped",
                                         "reason": reason}, indent=2) + "\n")
        md_path.write_text(f"# Soak: {scene}\n\nSkipped: {reason}.\n")
        print(f"soak {scene}: skipped — {reason}")
        return 0
    # The clean run of the same seed: the pipeline's own acquisition.
    reference = pd.read_parquet(processed_path(scene))
    with tempfile.TemporaryDirectory(prefix="eskin-soak-") as scratch:
        result = run_soak(params, settings, Path(scratch), reference, scene=scene,
                          kill_at=settings.kill_at)
    json_path.write_text(json.dumps(result.as_dict(), indent=2) + "\n")
    md_path.write_text(result.markdown())
    print(result.markdown())
    return 0 if result.passed else 1


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: main(sys.argv[1])))
