"""Training one task: :func:`train_task` cross-validates it under each CV scheme and
refits it on all the data, from features and folds in memory to scores, out-of-fold
predictions and models in memory. The train step (:mod:`eskin.steps.train`) reads its
inputs and writes what it returns. (A two-force scene's contacts are scored as sets by
eskin.evaluation.pairs.score_scene_pairs.)
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from eskin.config.cv import CV
from eskin.config.train import TaskModels
from eskin.data.schema import describe_source
from eskin.evaluation.crossval import cross_validate, fit_final, parallel_backend
from eskin.evaluation.tasks import Task, get_task
from eskin.kinds import Kind
from eskin.learning.choice import chosen_model
from eskin.learning.estimators import build_model
from eskin.skin import AnySkin


@dataclass(frozen=True)
class Trained:
    """What :func:`train_task` did: ``status`` is ``trained`` or ``skipped`` (``reason``);
    ``results`` the cross-validation of each scheme. What the step writes: ``header``
    (what trained on what, at the head of the scores and lineage), ``scores`` (the scores
    document after the header and the model file's md5), ``predictions`` (out of fold,
    every scheme), ``models`` (refit on all rows; a skipped task's reason) and
    ``hyperparameters``."""

    scene: str
    task: str
    model: str | None  # None: the kind has no labels for the task
    status: str
    summary: str
    reason: str = ""
    results: list = field(default_factory=list)
    header: dict = field(default_factory=dict)
    scores: dict = field(default_factory=dict)
    predictions: pd.DataFrame = field(default_factory=pd.DataFrame)
    models: Any = None
    hyperparameters: dict | None = None


def train_task(scene: str, task_name: str, frame: pd.DataFrame, *, meta: dict[str, Any],
               skin: AnySkin, data_kind: Kind, folds: dict[str, np.ndarray],
               fold_notes: dict[str, str], task_params: TaskModels | None,
               configuration: str, cv: CV, last_run: Mapping[str, Any] | None = None,
               log: Callable[[str], None] = lambda message: print(message, file=sys.stderr,
                                                                  flush=True)) -> Trained:
    """Cross-validate one task on the scene's folds (``folds``: scheme → its folds, as the
    folds step drew them; ``fold_notes``: where a scheme fell back from its strata), then
    refit on all rows; nothing is read or written (:mod:`eskin.steps.train` does both).
    ``frame`` is the features of the skin ``skin``, of the kind ``data_kind`` (a
    total-force variant's, where its labels say so), ``meta`` their metadata. A model that
    reads a row/column skin's terminals is replaced, on a channel array, by its generic
    model (:func:`~eskin.learning.choice.model_for_skin`), as is a localisation's logistic
    regression on a skin of long axes by PeakWindow, and the summary says so.

    ``task_params`` is the task's ``train.<task>`` section, ``configuration``
    ``train.configuration``; of ``cv`` only how folds run (``n_jobs``, ``backend``).
    ``last_run``: the task's record from its last training here (:mod:`eskin.steps.train`
    writes it); where it trained the same model, its seconds a fold say whether a pool of
    workers pays, so that no fold runs first to find out (results do not depend on it)."""
    kind = data_kind.name
    task = get_task(kind, task_name)
    header = {"scene": scene, "kind": kind, "task": task_name,
              "dataset_md5": meta["dataset"]["md5"], "dataset_rows": meta["dataset"]["rows"],
              "source": describe_source(meta)}
    model_name = estimator = hyper = model_note = None
    if task.targets:  # a task the kind has no labels for has no model to choose
        # the models are chosen per kind of scene, as params.yaml names them
        model_name, hyper, model_note = chosen_model(task_params, configuration,
                                                     data_kind.scene_kind, skin, task.role)
        estimator = build_model(task.role, model_name, hyper, skin)
        header["model"] = model_name
        if model_note:  # only where a model was replaced: the paper's scores keep their bytes
            header["model_note"] = model_note

    reason = task.unsupported(frame)
    if reason is not None:
        return Trained(scene, task_name, model_name, "skipped",
                       f"{scene}/{task_name}: skipped — {reason}", reason=reason,
                       header=header, models={"skipped": reason})

    results: list = []
    n_jobs = int(cv.n_jobs)
    last_run = last_run or {}
    fold_seconds = last_run.get("fold_seconds", {}) if last_run.get("model") == model_name else {}
    with parallel_backend(cv.backend):
        for scheme, scheme_folds in folds.items():
            # each scheme's first fold decides whether a pool pays (crossval.pool_pays),
            # unless the last run says: a scheme's folds differ in size from another's,
            # and a fold run here gets the threads a worker would, wherever it runs
            results.append(cross_validate(
                task, frame, scheme_folds, estimator, scheme, skin, probe=True,
                n_jobs=n_jobs, progress=f"{scene}/{task_name} [{model_name}] {scheme} CV",
                fold_seconds=fold_seconds.get(scheme)))
    log(f"{scene}/{task_name} [{model_name}]: refitting on all {len(frame):,} rows …")
    models = fit_final(task, frame, estimator, skin)
    scores: dict[str, Any] = {"status": "trained", "rows": int(task.rows(frame).sum()),
                              **{r.scheme: r.summary for r in results}}
    confusion = {r.scheme: r.confusion for r in results if r.confusion}
    if confusion:
        scores["confusion"] = confusion
    # only where a scheme fell back from its node strata: other scores keep their bytes
    noted = {r.scheme: fold_notes[r.scheme] for r in results if r.scheme in fold_notes}
    if noted:
        scores["fold_notes"] = noted
    predictions = pd.concat([r.predictions.assign(scheme=r.scheme) for r in results],
                            ignore_index=True)
    headline = ", ".join(f"{r.scheme} {_headline(task, r.summary)}" for r in results)
    notes = "".join(f"\n  note ({r.scheme}, {n} of {len(r.per_fold[next(iter(r.per_fold))])} "
                    f"folds): {text}" for r in results for text, n in sorted(r.notes.items()))
    notes = "".join(f"\n  note ({scheme} folds): {note}"
                    for scheme, note in noted.items()) + notes
    if model_note:
        notes = f"\n  note: {model_note}" + notes
    return Trained(scene, task_name, model_name, "trained",
                   f"{scene}/{task_name} [{model_name}]: {headline}{notes}", results=results,
                   header=header, scores=scores, predictions=predictions, models=models,
                   hyperparameters=hyper)


def _headline(task: Task, summary: dict[str, dict[str, float]]) -> str:
    """Each target's headline score, then each position's error in mm where there is one."""
    name = task.headline_metric
    return " ".join([f"{target} {name} {summary[target][name]:.3f}±"
                     f"{summary[target][name + '_std']:.3f}" for target in task.targets]
                    + [f"{position} error {summary[position]['error_mm']:.2f}±"
                       f"{summary[position]['error_mm_std']:.2f} mm"
                       for position in task.positions if position in summary])
