"""DVC stage: features and folds of a scene, and the model its settings name → one task's
scores, predictions, models, and the run's record for the tracking stage."""

import sys

from eskin.catalog import FEATURES_DIR, settings_path, task_outputs
from eskin.config.base import load_params, sections
from eskin.config.cv import CV
from eskin.config.scenes import Scenes, get_scene
from eskin.errors import run_friendly
from eskin.learning import train
from eskin.learning.settings import read_settings


def main(scene: str, task: str) -> str:
    params = load_params(sections(scenes=Scenes, cv=CV))
    get_scene(params, scene)
    task_params, configuration = read_settings(settings_path(scene, task), scene, task)
    return train.train(scene, task, task_params=task_params, configuration=configuration,
                       cv=params.cv, features_dir=FEATURES_DIR,
                       **task_outputs(scene, task)).summary


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(sys.argv[1], sys.argv[2]))))
