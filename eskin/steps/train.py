"""Features and folds of a scene, and the model its settings name → one task's scores,
predictions, models, and the run's record for the tracking stage."""

from __future__ import annotations

from pathlib import Path

from eskin.catalog import FEATURES_DIR, settings_path, task_outputs
from eskin.config.base import DEFAULT_PARAMS, load_params, sections
from eskin.config.cv import CV
from eskin.config.scenes import Scenes, get_scene
from eskin.learning import train
from eskin.learning.settings import read_settings


def run(scene: str, task: str, params_path: Path | str = DEFAULT_PARAMS) -> str:
    params = load_params(sections(scenes=Scenes, cv=CV), params_path)
    get_scene(params, scene, params_path)
    task_params, configuration = read_settings(settings_path(scene, task), scene, task)
    return train.train(scene, task, task_params=task_params, configuration=configuration,
                       cv=params.cv, features_dir=FEATURES_DIR,
                       **task_outputs(scene, task)).summary
