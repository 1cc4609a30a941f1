"""The yardstick of the loop's speed (issue 55): the pipeline's model fits, and nothing
else, in one plain process.

For each scene and task asked for, it reads the features and folds the pipeline wrote
(data/features/, data/folds/), builds the very estimator the training stage builds (the
same params.yaml settings, through eskin's model registry), and runs the same fits: every
CV scheme's folds, each fold's models fitted and predicting, the folds in parallel as the
pipeline runs them (``cv.n_jobs`` joblib workers), then the refit on all rows. It scores
nothing, saves nothing, logs nothing: what is left of the pipeline's wall once this is
taken away is what the pipeline costs beyond its fits.

    PYTHONPATH=. python -m harness.plain_fits [SCENE/TASK ...]   (default: every one)

It prints one line per task with its seconds, then the total, and (``--json``) writes them.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
from joblib import Parallel, delayed
from sklearn.base import clone

from eskin.catalog import TASK_NAMES
from eskin.config.base import load_params
from eskin.config.params import Params
from eskin.data.schema import dataset_kind, dataset_skin
from eskin.evaluation.tasks import get_task
from eskin.learning.choice import chosen_model
from eskin.learning.estimators import build_model


def _fold(estimator, X: pd.DataFrame, targets: pd.DataFrame, fold_of: np.ndarray, k: int):
    train, test = fold_of != k, fold_of == k
    return [clone(estimator).fit(X[train], targets[name][train]).predict(X[test])
            for name in targets]


def fold_predictions(estimator, X: pd.DataFrame, targets: pd.DataFrame, fold_of: np.ndarray,
                     n_jobs: int) -> dict[int, list[np.ndarray]]:
    """Each fold's predictions of every target (in ``targets``' order), the folds on
    ``n_jobs`` joblib workers; a row of fold -1 is trained on and never tested."""
    folds = sorted(set(fold_of) - {-1})
    return dict(zip(folds, Parallel(n_jobs=n_jobs)(
        delayed(_fold)(estimator, X, targets, fold_of, k) for k in folds), strict=True))


def fit_task(params: Params, scene: str, task_name: str, root: Path = Path("."),
             keep: bool = False) -> dict:
    """One task's CV fits under every scheme, then its refit: seconds, and whether it ran
    (a task the scene's data cannot support is skipped, as the pipeline skips it); with
    ``keep``, each scheme's fold predictions too (``predictions``)."""
    started = time.perf_counter()
    source = root / "data" / "features" / f"{scene}.parquet"
    frame = pd.read_parquet(source)
    folds = pd.read_parquet(root / "data" / "folds" / f"{scene}.parquet")
    skin, kind = dataset_skin(source), dataset_kind(source)
    task = get_task(kind.name, task_name)
    task_params = getattr(params.train, task_name)
    name, hyper, _ = chosen_model(task_params, params.train.configuration, kind.scene_kind,
                                  skin, task.role)
    estimator = build_model(task.role, name, hyper, skin)
    if task.unsupported(frame) is not None:
        return {"model": name, "seconds": time.perf_counter() - started, "skipped": True}
    rows = task.rows(frame)
    data = frame[rows].reset_index(drop=True)
    X = data[skin.channels].astype(np.float64)
    targets = pd.DataFrame(task.target_values(data))
    predictions = {}
    for scheme in (column for column in folds.columns if column != "trial"):
        predictions[scheme] = fold_predictions(estimator, X, targets,
                                               folds[scheme].to_numpy()[rows],
                                               int(params.cv.n_jobs))
    for target in targets:
        clone(estimator).fit(X, targets[target])
    return {"model": name, "seconds": time.perf_counter() - started, "skipped": False,
            **({"predictions": predictions, "targets": list(targets)} if keep else {})}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tasks", nargs="*", metavar="SCENE/TASK")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    started = time.perf_counter()
    params = load_params(Params)
    wanted = ([tuple(t.split("/", 1)) for t in args.tasks] if args.tasks
              else [(scene, task) for scene in params.scenes for task in TASK_NAMES])
    done = {}
    for scene, task in wanted:
        done[f"{scene}/{task}"] = fit_task(params, scene, task)
        print(f"{scene}/{task} [{done[f'{scene}/{task}']['model']}]: "
              f"{done[f'{scene}/{task}']['seconds']:.1f} s", file=sys.stderr, flush=True)
    result = {"tasks": done, "seconds": time.perf_counter() - started}
    print(f"plain fits: {result['seconds']:.1f} s (the process, imports aside)")
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
