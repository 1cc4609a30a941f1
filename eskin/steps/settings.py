"""params.yaml's train section → reports/settings/<scene>/<task>.json, the model and
hyperparameters each scene's task trains, so that each training step depends on its own
settings, not on a section shared by every kind of scene."""

from __future__ import annotations

from pathlib import Path

from eskin.catalog import TASK_NAMES, settings_path
from eskin.config.base import DEFAULT_PARAMS, load_params, sections
from eskin.config.scenes import Scenes
from eskin.config.train import Train
from eskin.learning.settings import write_settings


def run(params_path: Path | str = DEFAULT_PARAMS) -> str:
    params = load_params(sections(scenes=Scenes, train=Train), params_path)
    configuration = params.train.configuration
    written = [write_settings(settings_path(name, task), scene=name, kind=scene.kind,
                              task=task, configuration=configuration,
                              task_params=getattr(params.train, task))
               for name, scene in params.scenes.items() for task in TASK_NAMES]
    return "settings: " + ", ".join(f"{d['scene']}/{d['task']} {(d['train'] or {}).get('model')}"
                                    for d in written)
