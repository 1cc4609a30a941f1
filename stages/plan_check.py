"""DVC stage of `make bench`: the planner's answers for a scene's targets
(`learning_curve.checks`), recorded on fresh repetitions of the simulated skin and scored
on new recordings never trained on; fails when a plan misses (harness/plan_check.py)."""

import json
import sys

from eskin.catalog import learning_curve_path, plan_check_path
from eskin.config.base import BENCH_PARAMS, load_params, sections
from eskin.config.params import Params
from eskin.config.planning import LearningCurve
from eskin.config.scenes import get_scene
from eskin.errors import EskinError, run_friendly
from eskin.tracking.planning import read_curves
from harness import plan_check


def main(scene: str) -> str:
    params = load_params(Params)
    get_scene(params, scene)
    settings = load_params(sections(BENCH_PARAMS, learning_curve=LearningCurve)).learning_curve
    targets = [t for t in settings.checks if t.scene == scene]
    document = plan_check.check_plans(
        scene, params, read_curves(learning_curve_path(scene), scene), targets, settings,
        recordings=settings.check_recordings,
        log=lambda line: print(line, file=sys.stderr, flush=True))
    out = plan_check_path(scene)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(document, indent=2) + "\n")
    text = plan_check.render(document)
    out.with_suffix(".md").write_text(text)
    misses = plan_check.missed(document)
    if misses:
        raise EskinError(f"{scene}: the planner's answer missed on new recordings: "
                         f"{'; '.join(misses)} ({out})")
    return text


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(sys.argv[1]))))
