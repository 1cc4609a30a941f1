"""Verification harnesses, apart from the product: the benchmark and its Bayes bound, the
numerical stress suite, the link soak, the fuzzers and the import memory benchmark.
Run by `make bench` and `make stress` (bench/dvc.yaml, stress/dvc.yaml) and the tests."""
