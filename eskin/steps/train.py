"""Features and folds of a scene, and the model its settings name → one task's scores,
predictions, models, and the run's record for the tracking stage.

:func:`train_at` reads and writes; the training between is
:func:`eskin.learning.train.train_task`, which does neither."""

from __future__ import annotations

import os
import socket
import sys
import time
from collections.abc import Callable
from pathlib import Path

from eskin.catalog import FEATURES_DIR, settings_path, task_outputs
from eskin.config.base import DEFAULT_PARAMS, load_params, sections
from eskin.config.cv import CV
from eskin.config.scenes import Scenes, get_scene
from eskin.config.train import TaskModels
from eskin.data.schema import dataset_kind, dataset_skin, md5_file, read_dataset, read_metadata
from eskin.evaluation.folds import read_fold_notes, read_scene_folds
from eskin.evaluation.outputs import save_predictions, write_json
from eskin.learning.saved import save_models
from eskin.learning.settings import read_settings
from eskin.learning.train import Trained, train_task


def run(scene: str, task: str, params_path: Path | str = DEFAULT_PARAMS) -> str:
    params = load_params(sections(scenes=Scenes, cv=CV), params_path)
    get_scene(params, scene, params_path)
    task_params, configuration = read_settings(settings_path(scene, task), scene, task)
    return train_at(scene, task, task_params=task_params, configuration=configuration,
                    cv=params.cv, features_dir=FEATURES_DIR,
                    **task_outputs(scene, task)).summary


def train_at(scene: str, task: str, *, task_params: TaskModels | None, configuration: str,
             cv: CV, features_dir: Path, folds_path: Path, scores_path: Path,
             predictions_path: Path, model_path: Path, lineage_path: Path | None = None,
             record_path: Path | None = None,
             log: Callable[[str], None] = lambda message: print(message, file=sys.stderr,
                                                                flush=True)) -> Trained:
    """One task trained on the features in ``features_dir`` and the folds at
    ``folds_path`` (every scheme drawn once by the folds stage), its outputs written where
    the paths say (:func:`eskin.catalog.task_outputs` names the pipeline's).

    ``lineage_path`` (uncached in dvc.yaml, which turns DVC's run cache off for the
    stage): what trained the model. ``record_path`` (not a DVC output, so its times never
    reach dvc.lock): when and how long it ran, and each fold's scores, for the tracking
    stage (:mod:`eskin.tracking.runs`) to log; a task DVC reused has none."""
    started, started_at = time.perf_counter(), time.time()
    source = Path(features_dir) / f"{scene}.parquet"
    if not source.exists():
        raise FileNotFoundError(f"{source}: no features; run `dvc repro featurize@{scene}` first")
    frame = read_dataset(source)
    trained = train_task(scene, task, frame, meta=read_metadata(source),
                         skin=dataset_skin(source), data_kind=dataset_kind(source),
                         folds=read_scene_folds(folds_path, frame),
                         fold_notes=read_fold_notes(folds_path), task_params=task_params,
                         configuration=configuration, cv=cv, log=log)
    header, skipped = trained.header, trained.status == "skipped"
    save_models(trained.models, model_path)
    if not skipped:  # the model file's md5 (as in dvc.lock) links scores, DVC and MLflow
        header = {**header, "model_md5": md5_file(model_path)}
    write_json({**header, "status": "skipped", "reason": trained.reason} if skipped
               else {**header, **trained.scores}, scores_path)
    if lineage_path is not None:
        write_json({**header, "status": trained.status,
                    **({} if skipped else {"features_md5": md5_file(source)})}, lineage_path)
    save_predictions(trained.predictions, predictions_path)
    if record_path is not None and not skipped:
        results = trained.results
        write_json({"model_md5": header["model_md5"],
                    "hyperparameters": trained.hyperparameters,
                    "started": started_at, "ended": time.time(),
                    "wall_seconds": time.perf_counter() - started,
                    "host": socket.gethostname(), "pid": os.getpid(),
                    "timings": {r.scheme: {"fit_seconds": r.fit_seconds,
                                           "predict_seconds": r.predict_seconds}
                                for r in results},
                    "per_fold": {r.scheme: r.per_fold for r in results}}, record_path)
    return trained
