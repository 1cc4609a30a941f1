"""DVC stages of `make bench`, per scene: the Bayes bound, one task's variants timed
against error, and the summary."""

import sys

from eskin.catalog import bayes_bound_path, bench_dir, features_path, processed_path
from eskin.config.acquisition import Sim
from eskin.config.base import BENCH_PARAMS, load_params, sections
from eskin.config.cv import CV
from eskin.config.scenes import Scenes, get_scene
from eskin.config.train import Train
from eskin.errors import run_friendly
from harness import benchmark
from harness.params import Bench


def main(what: str, scene: str, task: str | None = None) -> str:
    params = load_params(sections(sim=Sim, scenes=Scenes, train=Train, cv=CV))
    get_scene(params, scene)
    bench = load_params(sections(BENCH_PARAMS, bench=Bench)).bench
    out = bench_dir(scene)
    if what == "bound":
        return benchmark.bayes_bound(scene, params.scenes[scene], processed_path(scene),
                                     bayes_bound_path(scene), sim=params.sim, seed=bench.seed)
    if what == "summary":
        return benchmark.summarise(scene, out, features_path(scene), bench=bench,
                                   train=params.train)
    return benchmark.bench(scene, task, features_path(scene), bayes_bound_path(scene), out,
                           bench=bench, cv=params.cv)


if __name__ == "__main__":
    # python -m stages.bench bound <scene> | bench <scene> <task> | summary <scene>
    sys.exit(run_friendly(lambda: print(main(*sys.argv[1:]))))
