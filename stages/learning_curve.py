"""DVC stage of `make bench`: a scene's learning curves, error against trials per
condition beside the Bayes bound, and what a target costs (harness/learning_curve.py)."""

import sys

from eskin.catalog import bayes_bound_path, learning_curve_path
from eskin.config.base import BENCH_PARAMS, load_params, sections
from eskin.config.params import Params
from eskin.config.planning import LearningCurve
from eskin.config.scenes import get_scene
from eskin.errors import run_friendly
from harness import learning_curve


def main(scene: str) -> str:
    params = load_params(Params)
    get_scene(params, scene)
    settings = load_params(sections(BENCH_PARAMS, learning_curve=LearningCurve)).learning_curve
    document = learning_curve.learning_curve(
        scene, params, list(settings.repeats), bound_path=bayes_bound_path(scene),
        gap_share=settings.gap_share, gap_tasks=tuple(settings.gap_tasks),
        draws=settings.draws, reliability=settings.reliability,
        log=lambda line: print(line, file=sys.stderr, flush=True))
    text = learning_curve.render(document, settings)
    learning_curve.write(document, text, learning_curve_path(scene).parent)
    return text


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(sys.argv[1]))))
