"""DVC stage of `make bench`: cross-validation on dask.distributed (1 and 2 workers)
against loky, and what goes over the wire (harness/dask_scaling.py)."""

import json
import sys
from pathlib import Path

from eskin.config.base import load_params, sections
from eskin.config.scenes import Scenes, get_scene
from eskin.errors import run_friendly
from harness.dask_scaling import measure, render

REPORT = Path("reports/dask_scaling")


def main(scene: str) -> int:
    get_scene(load_params(sections(scenes=Scenes)), scene)
    result = measure(scene)
    REPORT.mkdir(parents=True, exist_ok=True)
    (REPORT / f"{scene}.json").write_text(json.dumps(result, indent=2) + "\n")
    text = render(result) + "\n"
    (REPORT / f"{scene}.md").write_text(text)
    print(text)
    if not all(r["identical_predictions"] for r in result["dask"].values()):
        print("eskin: error: Dask's predictions differ from loky's", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: main(sys.argv[1])))
