"""Features and folds of a scene, and the models its settings name → each task's scores,
predictions, models, and the run's record for the publish stage.

A scene's tasks train in one process (the scene's train stage). A task is kept, not
trained again, when its features, folds, settings and code are those its lineage file
says it was trained from (:func:`task_inputs`): a knob of one task's model, or a CV
setting that changes no result (``cv.n_jobs``), refits only what it changes.

:func:`train_at` reads and writes; the training between is
:func:`eskin.learning.train.train_task`, which does neither."""

from __future__ import annotations

import json
import os
import socket
import sys
import time
from collections.abc import Callable
from pathlib import Path

from eskin.catalog import FEATURES_DIR, TASK_NAMES, folds_path, settings_path, task_outputs
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
from eskin.steps import code

INPUTS = ("code_md5", "features_md5", "folds_md5", "settings_md5")


def run(scene: str, task: str | None = None, params_path: Path | str = DEFAULT_PARAMS) -> str:
    """Train ``task`` of ``scene``, or every task (the stage), each unless kept."""
    params = load_params(sections(scenes=Scenes, cv=CV), params_path)
    get_scene(params, scene, params_path)
    said = []
    shared = scene_inputs(FEATURES_DIR / f"{scene}.parquet", folds_path(scene))
    for name in (task,) if task else TASK_NAMES:
        outputs = task_outputs(scene, name)
        inputs = task_inputs(settings_path(scene, name), shared)
        if kept(inputs, outputs):
            said.append(f"{scene}/{name}: kept, trained from these features, folds, settings "
                        f"and code ({outputs['lineage_path']})")
            continue
        task_params, configuration = read_settings(settings_path(scene, name), scene, name)
        said.append(train_at(scene, name, task_params=task_params, configuration=configuration,
                             cv=params.cv, features_dir=FEATURES_DIR, inputs=inputs,
                             **outputs).summary)
    return "\n".join(said)


def code_files() -> tuple[Path, ...]:
    """The code a task's training runs (:func:`eskin.steps.code.code_files` of this
    module): the files the train stage lists in dvc.yaml for it (a test compares the two)."""
    return code.code_files(__file__)


def code_md5() -> str:
    """The md5 of :func:`code_files` (:func:`eskin.steps.code.code_md5`)."""
    return code.code_md5(__file__)


def scene_inputs(features: Path, folds: Path) -> dict[str, str]:
    """What every task of a scene is trained from: the md5s of the code
    (:func:`code_md5`) and of the scene's features and folds."""
    return {"code_md5": code_md5(), "features_md5": _md5_of(features, "prepare"),
            "folds_md5": _md5_of(folds, "prepare")}


def task_inputs(settings: Path, scene: dict[str, str]) -> dict[str, str]:
    """What a task is trained from: its scene's inputs (:func:`scene_inputs`) and the md5
    of its settings file. Recorded in its lineage file."""
    return {**scene, "settings_md5": _md5_of(settings, "settings")}


def _md5_of(path: Path, stage: str) -> str:
    if not Path(path).exists():
        raise FileNotFoundError(f"{path}: missing; run `dvc repro {stage}"
                                f"{'' if stage == 'settings' else '@' + Path(path).stem}` first")
    return md5_file(path)


def kept(inputs: dict[str, str], outputs: dict[str, Path]) -> bool:
    """Whether a task's outputs are all there and its lineage says it was trained from
    ``inputs``."""
    lineage = outputs.get("lineage_path")
    if lineage is None or not all(Path(outputs[name]).exists() for name in
                                  ("lineage_path", "scores_path", "predictions_path",
                                   "model_path")):
        return False
    try:
        recorded = json.loads(Path(lineage).read_text())
    except (OSError, ValueError):
        return False
    return all(recorded.get(name) == inputs[name] for name in INPUTS)


def _last_run(record_path: Path | None) -> dict | None:
    """The task's record from its last training here: only a hint of how long its folds
    take, so none, or one that cannot be read, is no record."""
    try:
        record = json.loads(Path(record_path).read_text()) if record_path is not None else None
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) else None


def train_at(scene: str, task: str, *, task_params: TaskModels | None, configuration: str,
             cv: CV, features_dir: Path, folds_path: Path, scores_path: Path,
             predictions_path: Path, model_path: Path, lineage_path: Path | None = None,
             record_path: Path | None = None, inputs: dict[str, str] | None = None,
             log: Callable[[str], None] = lambda message: print(message, file=sys.stderr,
                                                                flush=True)) -> Trained:
    """One task trained on the features in ``features_dir`` and the folds at
    ``folds_path`` (every scheme drawn once by the folds step), its outputs written where
    the paths say (:func:`eskin.catalog.task_outputs` names the pipeline's).

    ``lineage_path`` (uncached in dvc.yaml, which turns DVC's run cache off for the
    stage): what trained the model, and from what (``inputs``, :func:`task_inputs`).
    ``record_path`` (not a DVC output, so its times never reach dvc.lock): when and how
    long it ran, and each fold's scores, for the publish stage (:mod:`eskin.tracking.runs`)
    to log; a task kept has none."""
    started, started_at = time.perf_counter(), time.time()
    source = Path(features_dir) / f"{scene}.parquet"
    if not source.exists():
        raise FileNotFoundError(f"{source}: no features; run `dvc repro prepare@{scene}` first")
    frame = read_dataset(source)
    trained = train_task(scene, task, frame, meta=read_metadata(source),
                         skin=dataset_skin(source), data_kind=dataset_kind(source),
                         folds=read_scene_folds(folds_path, frame),
                         fold_notes=read_fold_notes(folds_path), task_params=task_params,
                         configuration=configuration, cv=cv, last_run=_last_run(record_path),
                         log=log)
    header, skipped = trained.header, trained.status == "skipped"
    save_models(trained.models, model_path)
    if not skipped:  # the model file's md5 (as in dvc.lock) links scores, DVC and MLflow
        header = {**header, "model_md5": md5_file(model_path)}
    write_json({**header, "status": "skipped", "reason": trained.reason} if skipped
               else {**header, **trained.scores}, scores_path)
    save_predictions(trained.predictions, predictions_path)
    if record_path is not None and not skipped:
        results = trained.results
        write_json({"model_md5": header["model_md5"], "model": trained.model,
                    "hyperparameters": trained.hyperparameters,
                    "started": started_at, "ended": time.time(),
                    "wall_seconds": time.perf_counter() - started,
                    "host": socket.gethostname(), "pid": os.getpid(),
                    "timings": {r.scheme: {"fit_seconds": r.fit_seconds,
                                           "predict_seconds": r.predict_seconds}
                                for r in results},
                    "per_fold": {r.scheme: r.per_fold for r in results},
                    # whether the next run's folds go to a pool (eskin.learning.train)
                    "fold_seconds": {r.scheme: r.fold_seconds for r in results}}, record_path)
    if lineage_path is not None:  # last: a task is kept by it (:func:`kept`), so a Ctrl-C
        # before it leaves the task to be trained again, never kept half-written
        lineage = {**header, "status": trained.status, **(inputs or {})}
        if not skipped and "features_md5" not in lineage:  # hashed once, where inputs say
            lineage["features_md5"] = md5_file(source)
        write_json(lineage, lineage_path)
    return trained
