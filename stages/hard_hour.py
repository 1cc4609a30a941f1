"""DVC stage of `make bench`: the live stack on the harder hour of the simulated board
(issue 57, item 6), each part scored against its targets (harness/hard_hour.py)."""

import sys
import time
from pathlib import Path

from eskin.config.base import BENCH_PARAMS, load_params, sections
from eskin.config.params import Params
from eskin.config.scenes import get_scene
from eskin.data.plan import plan_from_params
from eskin.errors import run_friendly
from harness.hard_hour import describe, hard_script, render, score_hard, trained_stretches_mm
from harness.live_hour import batch_cv_scores, run, write_report, write_skipped_import
from harness.params import HardHour

REPORT = Path("reports/hard_hour")


def main(scene: str) -> int:
    params = load_params(Params)
    scene_params = get_scene(params, scene)
    settings = load_params(sections(BENCH_PARAMS, hard_hour=HardHour)).hard_hour
    if scene_params.source == "import":
        write_skipped_import(REPORT, scene, "Harder hour")
        return 0
    start = time.process_time()
    frame = run(scene, settings,
                steps_of=lambda plan, rest_mm: hard_script(settings, plan, rest_mm))
    plan = plan_from_params(scene, scene_params)
    stretches = trained_stretches_mm(plan, float(params.acquire.rest_length_mm))
    result = {"scene": scene, "stack": "onnx",
              **score_hard(frame, batch_cv_scores(scene), settings.targets),
              "script": describe(settings, stretches, plan),
              "run_cpu_s": round(time.process_time() - start)}  # board to scores
    write_report(REPORT, scene, result, render(scene, result))
    return 0


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: main(sys.argv[1])))
