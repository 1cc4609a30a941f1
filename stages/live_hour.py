"""DVC stage of `make bench`: the live stack on an hour of the simulated board, scored
against the script (harness/live_hour.py)."""

import json
import sys
from pathlib import Path

from eskin.config import BENCH_PARAMS, BenchParams, get_scene, load_params, scene_kind
from eskin.errors import run_friendly
from harness.live_hour import batch_cv_scores, render, run, score

REPORT = Path("reports/live_hour")


def main(scene: str) -> int:
    kind = scene_kind(get_scene(load_params(), scene))
    settings = load_params(BENCH_PARAMS, BenchParams).live_hour
    REPORT.mkdir(parents=True, exist_ok=True)
    if not kind.detects:
        result = {"scene": scene, "skipped": f"a {kind.name} stack detects no contact (it "
                  "reports two on every frame): there are no phantoms or misses to score"}
        text = f"# Live hour: {scene}\n\nSkipped: {result['skipped']}."
    else:
        frame = run(scene, settings)
        result = {"scene": scene, **score(frame, batch_cv_scores(scene)),
                  "script": (f"{settings.presses} presses of {settings.press_s:g} s, one of "
                             f"{settings.sustained_s:g} s"
                             + (" (re-tared 1 s after)" if settings.retare_after_sustained
                                else "")
                             + f", stretches to {settings.stretches_mm} mm, "
                             f"{settings.untouched_s:g} s untouched between, seed "
                             f"{settings.seed}")}
        text = render(scene, result)
    (REPORT / f"{scene}.json").write_text(json.dumps(result, indent=2) + "\n")
    (REPORT / f"{scene}.md").write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: main(sys.argv[1])))
