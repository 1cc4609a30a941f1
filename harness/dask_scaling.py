"""Cross-validation on a dask.distributed cluster against joblib's loky, in one process.

The same task, model and folds (a scene's default force model, conditions 10-fold, two
folds at a time) on: loky with 2 processes (the baseline, run first in the same
process), then a local cluster on 127.0.0.1 of 1 worker process with 2 threads and of 2
with 1 thread each. Each is run once to warm up (processes started, modules imported),
then timed. Printed: wall time and its ratio to loky, whether the predictions are
identical, and what the tasks (joblib's batches of folds) depended on, recorded on the
workers (:class:`ShippedData`): the data every task shares (features, targets, fold
numbers; sent to each worker once), and what a task has of its own. Each task also
carries its pickled call (the estimator and a fold number), not counted here.

    PYTHONPATH=. python -m harness.dask_scaling [--scene single_force] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from collections import Counter
from pathlib import Path

import pandas as pd
from distributed import Client, LocalCluster, WorkerPlugin
from joblib import parallel_config

from eskin.catalog import features_path
from eskin.config.base import load_params
from eskin.config.params import Params
from eskin.data.schema import dataset_skin, read_metadata
from eskin.evaluation.crossval import cross_validate
from eskin.evaluation.folds import assign_folds
from eskin.evaluation.tasks import get_task
from eskin.learning.choice import chosen_model
from eskin.learning.estimators import build_model

TASK = "force"


class ShippedData(WorkerPlugin):
    """On each worker: every task run, with the data it depended on (key → bytes)."""

    name = "eskin-shipped-data"

    def setup(self, worker) -> None:
        self.worker, self.runs = worker, []

    def transition(self, key, start, finish, **kwargs) -> None:
        if finish == "executing":
            state = self.worker.state.tasks.get(key)
            if state is not None:
                self.runs.append({dep.key: dep.nbytes for dep in state.dependencies})


def shipped(client: Client) -> dict:
    """What the tasks (joblib's batches of folds) depended on, from the workers' records:
    the bytes every task shared (sent to each worker once) and the bytes a task had
    alone, on average."""
    runs = [run for per_worker in client.run(
        lambda dask_worker: dask_worker.plugins[ShippedData.name].runs).values()
        for run in per_worker]
    counts = Counter(key for run in runs for key in run)
    shared = {key for key, n in counts.items() if n == len(runs)} if runs else set()
    sizes = {key: size for run in runs for key, size in run.items()}
    own = [sum(size for key, size in run.items() if key not in shared) for run in runs]
    return {"tasks": len(runs), "shared_bytes": sum(sizes[k] for k in shared),
            "own_bytes_per_task": sum(own) / len(own) if own else 0.0}


def clear(client: Client) -> None:
    client.run(lambda dask_worker: dask_worker.plugins[ShippedData.name].runs.clear())


def run_cv(scene: str, params: Params, backend: str, n_jobs: int) -> tuple[object, float]:
    frame = pd.read_parquet(features_path(scene))
    kind = read_metadata(features_path(scene))["kind"]
    skin = dataset_skin(features_path(scene))
    task = get_task(kind, TASK)
    cv = params.cv
    folds = assign_folds(frame, kind, "conditions", int(cv.folds), int(cv.seed), skin=skin)
    section = getattr(params.train, TASK)
    name, hyper, _ = chosen_model(section, "tuned", kind, skin, task.role)
    estimator = build_model(task.role, name, hyper, skin)
    started = time.perf_counter()
    with parallel_config(backend=backend):
        result = cross_validate(task, frame, folds, estimator, "conditions", skin, n_jobs=n_jobs)
    return result, time.perf_counter() - started


def measure(scene: str) -> dict:
    params = load_params(Params)
    run_cv(scene, params, "loky", 2)  # warm, as each cluster is: its workers started
    baseline, loky_s = run_cv(scene, params, "loky", 2)
    out = {"scene": scene, "task": TASK, "folds": len(baseline.per_fold[next(iter(
        baseline.per_fold))]), "loky_2_processes_s": loky_s, "dask": {}}
    # joblib asks a Dask cluster for as many jobs as it has threads, and runs one job in
    # the calling process: one worker gets the machine's two cores as two threads.
    for workers, threads in ((1, 2), (2, 1)):
        with LocalCluster(n_workers=workers, threads_per_worker=threads, processes=True,
                          host="127.0.0.1", dashboard_address=None,
                          silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
            client.register_plugin(ShippedData())
            run_cv(scene, params, "dask", -1)  # warm: workers import scikit-learn once
            clear(client)
            result, seconds = run_cv(scene, params, "dask", -1)
            identical = result.predictions.equals(baseline.predictions)
            out["dask"][f"{workers}x{threads}"] = {
                "workers": workers, "threads_per_worker": threads,
                "seconds": seconds, "ratio_to_loky": seconds / loky_s,
                                    "identical_predictions": bool(identical),
                                    **shipped(client)}
    return out


def render(result: dict) -> str:
    lines = [f"Cross-validation of {result['scene']}'s {result['task']} model "
             f"({result['folds']} conditions folds): dask.distributed against loky "
             f"(2 processes, {result['loky_2_processes_s']:.1f} s), in one process.", "",
             "| workers × threads | wall time | ÷ loky | identical predictions | tasks | "
             "shared by every task, sent to each worker once | each task's own |",
             "|---|---|---|---|---|---|---|"]
    for r in result["dask"].values():
        lines.append(f"| {r['workers']} × {r['threads_per_worker']} | {r['seconds']:.1f} s | "
                     f"{r['ratio_to_loky']:.2f} | "
                     f"{'yes' if r['identical_predictions'] else 'NO'} | {r['tasks']} | "
                     f"{r['shared_bytes'] / 1e6:.2f} MB | "
                     f"{r['own_bytes_per_task']:.0f} B |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", required=True, help="a scene of params.yaml")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    result = measure(args.scene)
    print(render(result))
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
