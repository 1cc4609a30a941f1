"""reports/settings/<scene>/<task>.json: the model and hyperparameters a scene's task
trains (written by the settings stage from params.yaml's ``train``, read by its training
stage), so that each training stage depends on its own settings, not on a section shared by
every kind of scene. Apart from eskin.learning.choice, so that what only chooses a model
(export, tracking) does not depend on the train section's schema."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from eskin.config.train import TaskModels
from eskin.evaluation.tasks import get_task
from eskin.learning.choice import task_section


def write_settings(path: Path, *, scene: str, kind: str, task: str, configuration: str,
                   task_params: TaskModels) -> dict[str, Any]:
    """One scene's task's settings file: its kind, ``train.configuration`` and
    :func:`task_section`; rewritten with the same bytes when nothing in it changed (so
    DVC does not rerun the task)."""
    # a task the kind has no labels for trains nothing (eskin.evaluation.tasks): no model
    labelled = bool(get_task(kind, task).targets)
    document = {"scene": scene, "kind": kind, "task": task, "configuration": configuration,
                "train": task_section(task_params, configuration, kind) if labelled else None}
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(document, indent=2, sort_keys=True) + "\n")
    return document


def read_settings(path: Path, scene: str, task: str) -> tuple[TaskModels | None, str]:
    """(``train.<task>`` section, ``train.configuration``) of a scene's task, from its
    settings file; None for a task its kind has no labels for."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no model settings for {scene}/{task}; run "
                                f"`dvc repro settings` first")
    document = json.loads(path.read_text())
    if (document.get("scene"), document.get("task")) != (scene, task):
        raise ValueError(f"{path} holds the settings of {document.get('scene')}/"
                         f"{document.get('task')}, not {scene}/{task}; run `dvc repro "
                         f"settings`")
    if document["train"] is None:
        return None, document["configuration"]
    return TaskModels.model_validate(document["train"]), document["configuration"]
