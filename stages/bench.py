"""DVC stages of `make bench`, per scene: the Bayes bound, one task's variants timed
against error, and the summary."""

import sys

from eskin.catalog import bayes_bound_path, bench_dir, features_path, processed_path
from eskin.config import load_params
from eskin.errors import run_friendly
from harness import benchmark


def main(what: str, scene: str, task: str | None = None) -> str:
    params = load_params()
    out = bench_dir(scene)
    if what == "bound":
        return benchmark.bayes_bound(params, scene, processed_path(scene),
                                     bayes_bound_path(scene))
    if what == "summary":
        return benchmark.summarise(params, scene, out, features_path(scene))
    return benchmark.bench(params, scene, task, features_path(scene),
                           bayes_bound_path(scene), out)


if __name__ == "__main__":
    # python -m stages.bench bound <scene> | bench <scene> <task> | summary <scene>
    sys.exit(run_friendly(lambda: print(main(*sys.argv[1:]))))
