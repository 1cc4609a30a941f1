"""DVC stage of `make bench`: how fast a scene's trained stack runs live
(harness/live_latency.py)."""

import json
import sys
from pathlib import Path

from eskin.config.base import load_params, sections
from eskin.config.scenes import Scenes, get_scene
from eskin.errors import run_friendly
from harness.live_latency import FRAMES, measure, render

REPORT = Path("reports/live_latency")


def main(scene: str) -> int:
    get_scene(load_params(sections(scenes=Scenes)), scene)
    result = measure(scene, FRAMES)
    REPORT.mkdir(parents=True, exist_ok=True)
    (REPORT / f"{scene}.json").write_text(json.dumps(result, indent=2) + "\n")
    text = render([result]) + "\n"
    (REPORT / f"{scene}.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: main(sys.argv[1])))
