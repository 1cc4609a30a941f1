"""Pipeline steps of learning, shared by the DVC stages and the command line.

``train`` cross-validates one task of a scene under each CV scheme, refits it
on all the data, and saves scores, out-of-fold predictions, models and a record of the
run (which the tracking stage logs to MLflow). (A two-force scene's contacts are scored
as sets by eskin.evaluation.pairs.score_scene_pairs.)
"""

from __future__ import annotations

import os
import socket
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from eskin.config.cv import CV
from eskin.config.train import TaskModels
from eskin.data.schema import (
    dataset_kind,
    dataset_skin,
    describe_source,
    md5_file,
    read_dataset,
    read_metadata,
)
from eskin.evaluation.crossval import cross_validate, fit_final, parallel_backend
from eskin.evaluation.folds import read_fold_notes, read_scene_folds
from eskin.evaluation.outputs import save_predictions, write_json
from eskin.evaluation.tasks import Task, get_task
from eskin.learning.choice import chosen_model
from eskin.learning.estimators import build_model
from eskin.learning.saved import save_models


@dataclass(frozen=True)
class Trained:
    """What :func:`train` did: ``status`` is ``trained`` or ``skipped`` (``reason``);
    ``results`` the cross-validation of each scheme."""

    scene: str
    task: str
    model: str | None  # None: the kind has no labels for the task
    status: str
    summary: str
    reason: str = ""
    results: list = field(default_factory=list)


def train(scene: str, task_name: str, *, task_params: TaskModels | None, configuration: str, cv: CV,
          features_dir: Path, folds_path: Path, scores_path: Path, predictions_path: Path,
          model_path: Path, lineage_path: Path | None = None, record_path: Path | None = None,
          log: Callable[[str], None] = lambda message: print(message, file=sys.stderr,
                                                               flush=True)) -> Trained:
    """Cross-validate one task on the scene's folds (``folds_path``, every scheme drawn
    once by the folds stage; a progress bar per scheme), refit and save, on the skin the
    features were taken on. A model that reads a row/column skin's terminals is replaced,
    on a channel array, by its generic model
    (:func:`~eskin.learning.choice.model_for_skin`), as is a localisation's logistic regression
    on a skin of long axes by PeakWindow, and the summary says so.

    ``task_params`` is the task's ``train.<task>`` section, ``configuration``
    ``train.configuration``; of ``cv`` only how folds run (``n_jobs``, ``backend``).

    ``lineage_path`` (uncached in dvc.yaml, which turns DVC's run cache off for the
    stage): what trained the model. ``record_path`` (not a DVC output, so its times never
    reach dvc.lock): when and how long it ran, and each fold's scores, for the tracking
    stage (:mod:`eskin.tracking.runs`) to log; a task DVC reused has none.
    """
    started, started_at = time.perf_counter(), time.time()
    source = Path(features_dir) / f"{scene}.parquet"
    if not source.exists():
        raise FileNotFoundError(f"{source}: no features; run `dvc repro featurize@{scene}` first")
    meta = read_metadata(source)
    frame = read_dataset(source)
    skin = dataset_skin(source)
    # the dataset's kind (a total-force variant's name, where its labels say so); the
    # models are chosen per kind of scene, as params.yaml names them
    the_kind = dataset_kind(source)
    kind = the_kind.name
    task = get_task(kind, task_name)
    header = {"scene": scene, "kind": kind, "task": task_name,
              "dataset_md5": meta["dataset"]["md5"], "dataset_rows": meta["dataset"]["rows"],
              "source": describe_source(meta)}
    model_name = estimator = None
    if task.targets:  # a task the kind has no labels for has no model to choose
        model_name, hyper, model_note = chosen_model(task_params, configuration,
                                                     the_kind.scene_kind, skin, task.role)
        estimator = build_model(task.role, model_name, hyper, skin)
        header["model"] = model_name
        if model_note:  # only where a model was replaced: the paper's scores keep their bytes
            header["model_note"] = model_note

    reason = task.unsupported(frame)
    if reason is not None:
        if lineage_path is not None:
            write_json({**header, "status": "skipped"}, lineage_path)
        write_json({**header, "status": "skipped", "reason": reason}, scores_path)
        save_predictions(pd.DataFrame(), predictions_path)
        save_models({"skipped": reason}, model_path)
        return Trained(scene, task_name, model_name, "skipped",
                       f"{scene}/{task_name}: skipped — {reason}", reason=reason)

    results: list = []
    n_jobs = int(cv.n_jobs)
    with parallel_backend(cv.backend):
        for scheme, folds in read_scene_folds(folds_path, frame).items():
            # the first scheme's first fold decides whether a pool pays (crossval.pool_pays)
            results.append(cross_validate(
                task, frame, folds, estimator, scheme, skin, probe=not results,
                n_jobs=n_jobs if not results or results[0].pooled else 1,
                progress=f"{scene}/{task_name} [{model_name}] {scheme} CV"))
    log(f"{scene}/{task_name} [{model_name}]: refitting on all {len(frame):,} rows …")
    models = fit_final(task, frame, estimator, skin)
    save_models(models, model_path)
    # The model file's md5 (as in dvc.lock) links scores, DVC and the MLflow run.
    header["model_md5"] = md5_file(model_path)
    scores_doc = {**header, "status": "trained", "rows": int(task.rows(frame).sum()),
                  **{r.scheme: r.summary for r in results}}
    confusion = {r.scheme: r.confusion for r in results if r.confusion}
    if confusion:
        scores_doc["confusion"] = confusion
    # only where a scheme fell back from its node strata: other scores keep their bytes
    written = read_fold_notes(folds_path)
    fold_notes = {r.scheme: written[r.scheme] for r in results if r.scheme in written}
    if fold_notes:
        scores_doc["fold_notes"] = fold_notes
    write_json(scores_doc, scores_path)
    if lineage_path is not None:
        write_json({**header, "status": "trained", "features_md5": md5_file(source)},
                   lineage_path)
    save_predictions(pd.concat([r.predictions.assign(scheme=r.scheme) for r in results],
                               ignore_index=True), predictions_path)
    if record_path is not None:
        write_json({"model_md5": header["model_md5"], "hyperparameters": hyper,
                    "started": started_at, "ended": time.time(),
                    "wall_seconds": time.perf_counter() - started,
                    "host": socket.gethostname(), "pid": os.getpid(),
                    "timings": {r.scheme: {"fit_seconds": r.fit_seconds,
                                           "predict_seconds": r.predict_seconds}
                                for r in results},
                    "per_fold": {r.scheme: r.per_fold for r in results}}, record_path)
    headline = ", ".join(f"{r.scheme} {_headline(task, r.summary)}" for r in results)
    notes = "".join(f"\n  note ({r.scheme}, {n} of {len(r.per_fold[next(iter(r.per_fold))])} "
                    f"folds): {text}" for r in results for text, n in sorted(r.notes.items()))
    notes = "".join(f"\n  note ({scheme} folds): {note}"
                    for scheme, note in fold_notes.items()) + notes
    if model_note:
        notes = f"\n  note: {model_note}" + notes
    return Trained(scene, task_name, model_name, "trained",
                   f"{scene}/{task_name} [{model_name}]: {headline}{notes}", results=results)


def _headline(task: Task, summary: dict[str, dict[str, float]]) -> str:
    """Each target's headline score, then each position's error in mm where there is one."""
    name = task.headline_metric
    return " ".join([f"{target} {name} {summary[target][name]:.3f}±"
                     f"{summary[target][name + '_std']:.3f}" for target in task.targets]
                    + [f"{position} error {summary[position]['error_mm']:.2f}±"
                       f"{summary[position]['error_mm_std']:.2f} mm"
                       for position in task.positions if position in summary])
