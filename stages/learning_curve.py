"""DVC stage of `make bench`: a scene's learning curves, error against trials per
condition beside the Bayes bound, and what a target costs (harness/learning_curve.py)."""

import sys

from eskin.catalog import bayes_bound_path, learning_curve_path
from eskin.config import BENCH_PARAMS, BenchParams, get_scene, load_params
from eskin.errors import run_friendly
from harness import learning_curve


def main(scene: str) -> str:
    params = load_params()
    get_scene(params, scene)
    settings = load_params(BENCH_PARAMS, BenchParams).learning_curve
    document = learning_curve.learning_curve(
        scene, params, list(settings.repeats), bound_path=bayes_bound_path(scene),
        gap_share=settings.gap_share, gap_tasks=tuple(settings.gap_tasks),
        log=lambda line: print(line, file=sys.stderr, flush=True))
    text = learning_curve.render(document, settings)
    learning_curve.write(document, text, learning_curve_path(scene).parent)
    return text


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(sys.argv[1]))))
