"""Cross-validate a task: out-of-fold predictions, per-fold scores, a final refit.

Folds run in parallel through joblib (``n_jobs``) under whatever backend
``joblib.parallel_config`` sets, so a Dask cluster takes them without code
changes: ``cv.backend`` in params.yaml (see ``parallel_backend``).
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from collections import Counter
from collections.abc import Callable, Mapping
from concurrent.futures import CancelledError
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
import pandas as pd
from joblib import Parallel, cpu_count, delayed, parallel_config
from sklearn.base import BaseEstimator, clone
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from eskin.evaluation import metrics
from eskin.evaluation.folds import FoldSplit, fold_splitter
from eskin.evaluation.tasks import Task
from eskin.skin import AnySkin


@dataclass
class CVResult:
    """One scheme's outcome: predictions per row, scores per fold and summarised."""

    scheme: str
    predictions: pd.DataFrame              # the task's rows: labels, fold, <target>_pred
    per_fold: dict[str, list[dict[str, float]]]   # target (or position) → one dict per fold
    summary: dict[str, dict[str, float]]   # target (or position) → mean and std of each score
    confusion: dict[str, dict[str, list]] = field(default_factory=dict)
    fit_seconds: float = 0.0               # summed over folds
    predict_seconds: float = 0.0
    notes: dict[str, int] = field(default_factory=dict)  # fit remark → folds that made it
    pooled: bool = False  # whether folds went to the n_jobs workers (:func:`pool_pays`)

    @property
    def fold_seconds(self) -> float:
        """A fold's fit and predict seconds, on average (``fold_seconds`` of a later run)."""
        folds = max((len(scores) for scores in self.per_fold.values()), default=0)
        return (self.fit_seconds + self.predict_seconds) / max(folds, 1)


LOKY_IDLE_S = 10
# Starting a process pool costs a stage one to three seconds on this machine (each worker
# imports scikit-learn). The first fold runs here and times the rest: they go to the
# workers where that saves more than the pool costs (:func:`pool_pays`), and run here
# otherwise. A fold run here gets the BLAS and OpenMP threads a worker would (joblib gives
# each cpu_count // n_jobs), as the thread count moves a model's last digits: where a
# fold runs changes no result.
POOL_STARTS_S = 2.0


def pool_pays(fold_s: float, remaining: int, n_jobs: int) -> bool:
    """Whether ``remaining`` folds of ``fold_s`` seconds each finish sooner on ``n_jobs``
    workers, once the pool's start (:data:`POOL_STARTS_S`) is paid. (Until issue 55 a fold
    had to take a second or more, so that 20 folds of 0.7 s, the force model's, ran on one
    core of two.)"""
    return fold_s * remaining * (1 - 1 / n_jobs) > POOL_STARTS_S


# How many times a sweep sends the data its folds share to a Dask cluster that loses it
# (:func:`_shared_with_cluster`): a worker killed now and then is survived, a cluster that
# keeps losing it is an error.
SHARED_DATA_SENDS = 3
DASK_CONNECT_S = 30        # a lab cluster that does not answer in this long is an error
NO_WORKERS_S = 120         # a local cluster's task with no worker left fails after this long


def parallel_backend(name: str = "loky"):
    """The joblib backend folds run on, as a context manager.

    ``loky`` (processes, joblib's default), ``threading`` and ``sequential`` are
    joblib's own. ``dask`` runs them on a ``dask.distributed`` cluster: the one
    ``DASK_SCHEDULER_ADDRESS`` names (a lab's, ``tcp://host:8786``), else the client
    already open in this process, else a local cluster on 127.0.0.1. The features,
    targets and the fold splitter go to every worker once per cross-validation, not with
    every fold (:func:`_shared_with_cluster`); a fold whose worker dies is run again on
    another. Results do not depend on the backend.
    """
    if name == "dask":
        _dask_client()
    if name == "loky":
        # Idle workers exit after this long: a stage killed outright (SIGKILL) cannot stop
        # its workers, and joblib's default would leave them alive for five minutes.
        return parallel_config(backend=name, idle_worker_timeout=LOKY_IDLE_S)
    return parallel_config(backend=name)


def _dask_client():
    try:
        import dask
        from distributed import Client, LocalCluster, default_client
    except ImportError as err:
        raise ValueError("cv.backend: dask needs dask.distributed installed "
                         "(pip install 'dask[distributed]')") from err
    address = os.environ.get("DASK_SCHEDULER_ADDRESS")
    try:
        client = default_client()
        if not address or client.scheduler.address == address:
            return client
    except ValueError:
        pass
    if address:
        try:
            return Client(address, timeout=DASK_CONNECT_S, set_as_default=True)
        except OSError as err:
            raise ValueError(f"no Dask scheduler answered at {address} "
                             f"(DASK_SCHEDULER_ADDRESS) within {DASK_CONNECT_S} s: {err}"
                             ) from None
    with dask.config.set({"distributed.scheduler.no-workers-timeout": f"{NO_WORKERS_S}s"}):
        return Client(LocalCluster(host="127.0.0.1", dashboard_address=None,
                                   threads_per_worker=1))


def _shared_with_cluster(*data):
    """Under the dask backend, ``data`` sent to every worker before the folds (joblib's
    ``scatter``, broadcast): a fold whose worker dies runs on another that has it. Left
    to joblib, each would be scattered to one worker, and lost with it.

    Dask's Active Memory Manager (on by default) still trims the copies, every 2 s, to
    the workers that have folds waiting for them: a worker killed then may hold the last
    one, and the folds left fail ("already forgotten"). :func:`cross_validate` then sends
    the data again and runs the folds left (:data:`SHARED_DATA_SENDS`)."""
    from joblib.parallel import get_active_backend

    backend, _ = get_active_backend()
    if type(backend).__name__ != "DaskDistributedBackend":
        return contextlib.nullcontext()
    return parallel_config(backend="dask", scatter=list(data))


def decision_scores(model: BaseEstimator, X: np.ndarray) -> np.ndarray | None:
    """A binary classifier's continuous score for the positive class (for ROC curves)."""
    if hasattr(model, "decision_function"):
        return np.asarray(model.decision_function(X), dtype=float)
    if hasattr(model, "predict_proba"):
        return np.asarray(model.predict_proba(X), dtype=float)[:, 1]
    return None


def channel_frame(X: np.ndarray, channels: list[str]) -> pd.DataFrame:
    """Rows of readings as a frame of the skin's channels, by name (a model that reads the
    terminals by name needs them: :func:`eskin.learning.estimators.row_column_skin`). It
    wraps ``X`` without a copy, so a model computes on the very array, in its memory
    order, and on the same numbers as from ``X`` itself."""
    return pd.DataFrame(X, columns=channels, copy=False)


class FoldOutcome(NamedTuple):
    """What one fold gives back: each target's predictions on its test rows, the seconds
    spent fitting and predicting (summed over targets), the fits' remarks, each target's
    decision scores (a binary task's), and, where asked, each target's fitted
    hyperparameters."""

    predictions: dict[str, np.ndarray]
    fit_seconds: float
    predict_seconds: float
    notes: set[str]
    scores: dict[str, np.ndarray | None]
    hyperparameters: dict[str, Any]


def _fit_predict_fold(estimator: BaseEstimator | Mapping[str, BaseEstimator], X: np.ndarray,
                      channels: list[str], targets: pd.DataFrame, splitter: FoldSplit, k: int,
                      binary: bool, hyperparameters: bool = False) -> FoldOutcome:
    """Fold ``k``: a clone of ``estimator`` (or of each target's, given by target name)
    fitted per target and timed."""
    train, test = splitter.fold(k)
    X_train, X_test = channel_frame(X[train], channels), channel_frame(X[test], channels)
    predictions, fit_s, predict_s, notes, scores, fitted = {}, 0.0, 0.0, set(), {}, {}
    for name in targets.columns:
        y = targets[name].to_numpy()
        model = clone(estimator[name] if isinstance(estimator, Mapping) else estimator)
        start = time.perf_counter()
        model.fit(X_train, y[train])
        fit_s += time.perf_counter() - start
        start = time.perf_counter()
        predictions[name] = np.asarray(model.predict(X_test))
        predict_s += time.perf_counter() - start
        if binary:
            scores[name] = decision_scores(model, X_test)
        notes.update(f"{name}: {note}" for note in getattr(model, "convergence_warnings_", []))
        if hyperparameters:
            if not hasattr(model, "hyperparameters_"):
                raise ValueError(f"share_hyperparameters: {type(model).__name__} fits no "
                                 "hyperparameters to share; drop it from the variant")
            fitted[name] = model.hyperparameters_
    return FoldOutcome(predictions, fit_s, predict_s, notes, scores, fitted)


def sharing_hyperparameters(estimator: BaseEstimator,
                            fitted: Mapping[str, Any]) -> dict[str, BaseEstimator]:
    """Each target's ``estimator`` given the hyperparameters fitted for it (by a first
    fold): later fits only condition on their data."""
    return {name: clone(estimator).set_params(hyperparameters=hyper)
            for name, hyper in fitted.items()}


def cross_validate(task: Task, frame: pd.DataFrame, folds: np.ndarray, estimator: BaseEstimator,
                   scheme: str, skin: AnySkin, *, n_jobs: int = 1, probe: bool = False,
                   progress: str | None = None, n_folds: int | None = None,
                   share_hyperparameters: bool = False,
                   fold_seconds: float | None = None) -> CVResult:
    """Score ``estimator`` on ``task`` over the given fold assignment of ``frame``'s rows,
    readings of ``skin``; where the skin places its nodes in mm, each contact's position
    error in mm too.

    ``n_jobs``: folds in parallel; with ``probe``, only if the first fold, run here, says
    that a pool pays (:func:`pool_pays`; ``CVResult.pooled`` says which), or
    ``fold_seconds``, a fold's seconds in an earlier run of the same model: then no fold
    waits alone for the answer, on one core of the pool's (issue 55).
    ``progress``: a label, and a progress bar of the folds on stderr (as they finish).
    ``n_folds``: only the first so many folds are run (the bench's ``evaluate_folds``);
    the other folds' rows are trained on, not predicted.
    ``share_hyperparameters``: the first fold, run here, fits each target's hyperparameters
    (a model with ``hyperparameters_``, such as the sparse GP) and the other folds reuse
    them (:func:`sharing_hyperparameters`)."""
    rows = task.rows(frame)
    data = frame[rows].reset_index(drop=True)
    fold_of = np.asarray(folds)[rows]
    channels = skin.channels
    X = data[channels].to_numpy(dtype=np.float64)
    targets = task.target_values(data)
    splitter = fold_splitter(fold_of, n_folds)
    splits = list(splitter.split(X))
    binary = task.scorer == "detection"
    # What every fold shares goes to a cluster's workers once (each fold task carries its
    # position in the splitter, and takes its rows from it: not its index arrays): the
    # targets as one frame, not a dict, which joblib would send with every task.
    target_frame = pd.DataFrame(targets)
    with tqdm(total=len(splits), desc=progress, unit="fold", disable=progress is None,
              file=sys.stderr, leave=False) as bar:
        outcomes: list[FoldOutcome] = []
        later = estimator  # what the folds after the first fit
        probing = probe and n_jobs != 1
        workers = cpu_count() if n_jobs < 0 else n_jobs
        in_process = False  # every fold run here: a pool would not pay
        if probing and fold_seconds is not None:
            probing, in_process = False, not pool_pays(fold_seconds, len(splits), workers)
        if splits and (probing or in_process or share_hyperparameters):
            with (threadpool_limits(max(cpu_count() // n_jobs, 1)) if probing or in_process
                  else contextlib.nullcontext()):
                started = time.perf_counter()
                outcomes.append(_fit_predict_fold(estimator, X, channels, target_frame,
                                                  splitter, 0, binary, share_hyperparameters))
                bar.update()
                if share_hyperparameters:
                    later = sharing_hyperparameters(estimator, outcomes[0].hyperparameters)
                if in_process or (probing and not pool_pays(time.perf_counter() - started,
                                                            len(splits) - 1, workers)):
                    for k in range(1, len(splits)):
                        outcomes.append(_fit_predict_fold(later, X, channels,
                                                          target_frame, splitter, k, binary))
                        bar.update()
        pooled = len(outcomes) < len(splits) and n_jobs != 1
        for send in range(1, SHARED_DATA_SENDS + 1):
            if len(outcomes) == len(splits):
                break
            shared = _shared_with_cluster(X, target_frame, splitter)
            try:
                with shared:
                    for outcome in Parallel(n_jobs=n_jobs, return_as="generator")(
                            delayed(_fit_predict_fold)(later, X, channels, target_frame,
                                                       splitter, k, binary)
                            for k in range(len(outcomes), len(splits))):
                        outcomes.append(outcome)
                        bar.update()
            except CancelledError as err:  # the cluster lost the data the folds share
                if isinstance(shared, contextlib.nullcontext) or send == SHARED_DATA_SENDS:
                    raise
                print(f"{progress or 'cross-validation'}: the Dask cluster lost the data the "
                      f"folds share ({err}); sending it again for the {len(splits) - len(outcomes)}"
                      " fold(s) left", file=sys.stderr, flush=True)

    score: Callable = metrics.SCORERS[task.scorer]
    predictions = data.drop(columns=channels).assign(fold=fold_of)
    per_fold: dict[str, list[dict[str, float]]] = {name: [] for name in targets}
    for (_, test), outcome in zip(splits, outcomes, strict=True):
        predicted, scores = outcome.predictions, outcome.scores
        for name, values in predicted.items():
            columns = {f"{name}_pred": values}
            if scores.get(name) is not None:
                columns[f"{name}_score"] = scores[name]
            for column, column_values in columns.items():
                if column not in predictions:
                    predictions[column] = pd.Series(pd.NA, index=predictions.index,
                                                    dtype=_dtype(column_values))
                predictions.loc[test, column] = column_values
            per_fold[name].append(score(targets[name][test], values, scores.get(name)))
        if skin.x_mm is not None and skin.y_mm is not None:
            for position, (x, y) in task.positions.items():
                per_fold.setdefault(position, []).append(metrics.position_error_mm(
                    targets[x][test], targets[y][test], predicted[x], predicted[y],
                    skin.x_mm, skin.y_mm))
    for name, values in targets.items():
        predictions[f"{name}_true"] = values
    confusion = {}
    if task.scorer != "regression":
        # a row no fold tests (-1: training only, or a fold beyond n_folds) has no prediction
        tested = np.zeros(len(fold_of), dtype=bool)
        for _, test in splits:
            tested[test] = True
        confusion = {name: metrics.confusion(
            targets[name][tested], predictions.loc[tested, f"{name}_pred"].to_numpy())
            for name in targets}
    return CVResult(
        scheme=scheme, predictions=predictions, per_fold=per_fold,
        summary={name: metrics.summarise(scores) for name, scores in per_fold.items()},
        confusion=confusion,
        fit_seconds=sum(o.fit_seconds for o in outcomes),
        predict_seconds=sum(o.predict_seconds for o in outcomes),
        notes=dict(Counter(note for o in outcomes for note in o.notes)), pooled=pooled)


def _dtype(values: np.ndarray) -> str:
    if values.dtype == bool:
        return "boolean"
    return "Int64" if np.issubdtype(values.dtype, np.integer) else "Float64"


def fit_final(task: Task, frame: pd.DataFrame, estimator: BaseEstimator,
              skin: AnySkin) -> dict[str, BaseEstimator]:
    """The task's models refit on all its rows (readings of ``skin``): target name →
    fitted estimator.

    Fitted on named columns, so that a deployed model refuses channels in the
    wrong order instead of predicting from them.
    """
    data = frame[task.rows(frame)]
    X = data[skin.channels].astype(np.float64)
    return {name: clone(estimator).fit(X, y) for name, y in task.target_values(data).items()}
