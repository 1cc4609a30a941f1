"""DVC stage of `make bench`: the live stack on an hour of the simulated board, scored
against the script (harness/live_hour.py)."""

import sys
from pathlib import Path

from eskin.config.base import BENCH_PARAMS, load_params, sections
from eskin.config.params import Params
from eskin.config.scenes import get_scene, scene_kind
from eskin.errors import run_friendly
from harness.live_hour import (
    batch_cv_scores,
    render,
    run,
    score,
    score_pairs,
    write_report,
    write_skipped_import,
)
from harness.params import LiveHour

REPORT = Path("reports/live_hour")


def main(scene: str) -> int:
    scene_params = get_scene(load_params(Params), scene)
    kind = scene_kind(scene_params)
    settings = load_params(sections(BENCH_PARAMS, live_hour=LiveHour)).live_hour
    if scene_params.source == "import":
        write_skipped_import(REPORT, scene, "Live hour")
        return 0
    frame = run(scene, settings)
    scored = score_pairs(frame, batch_cv_scores(scene)) if kind.several else \
        score(frame, batch_cv_scores(scene))
    result = {"scene": scene, **scored,
              "script": (f"{settings.presses} presses of {settings.press_s:g} s, one of "
                         f"{settings.sustained_s:g} s"
                         + (" (re-tared 1 s after)" if settings.retare_after_sustained
                            else "")
                         + f", each ramping over {settings.press_ramp_ms:g} ms, "
                         + (f"stretches to {frame.attrs['stretches_mm']} mm"
                            if frame.attrs["stretches_mm"] else "no stretch change")
                         + " (of the bench's, those the scene was trained on), "
                         f"{settings.untouched_s:g} s untouched between, seed "
                         f"{settings.seed}")}
    write_report(REPORT, scene, result, render(scene, result))
    return 0


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: main(sys.argv[1])))
