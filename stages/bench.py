"""DVC stages of `make bench`: the Bayes bound, and one task's variants timed against error."""

import sys

from eskin.catalog import FEATURES_DIR, PROCESSED_DIR
from eskin.config import load_params
from eskin.errors import run_friendly
from harness import benchmark

BENCH_DIR = "reports/benchmark"

if __name__ == "__main__":
    what = sys.argv[1]
    if what == "bound":
        sys.exit(run_friendly(lambda: print(benchmark.bayes_bound(
            load_params(), PROCESSED_DIR / "single_force.parquet",
            f"{BENCH_DIR}/bayes_bound.parquet"))))
    if what == "summary":
        sys.exit(run_friendly(lambda: print(benchmark.summarise(
            load_params(), BENCH_DIR, FEATURES_DIR / "single_force.parquet"))))
    sys.exit(run_friendly(lambda: print(benchmark.bench(
        load_params(), what, FEATURES_DIR / "single_force.parquet",
        f"{BENCH_DIR}/bayes_bound.parquet", BENCH_DIR))))
