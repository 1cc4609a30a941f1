"""DVC stage: params.yaml's train section → reports/settings/<scene>/<task>.json, the model
and hyperparameters each scene's task trains, so that each training stage depends on its
own settings, not on a section shared by every kind of scene."""

import sys

from eskin.catalog import TASK_NAMES, settings_path
from eskin.config.base import load_params, sections
from eskin.config.scenes import Scenes
from eskin.config.train import Train
from eskin.errors import run_friendly
from eskin.learning.settings import write_settings


def main() -> str:
    params = load_params(sections(scenes=Scenes, train=Train))
    configuration = params.train.configuration
    written = [write_settings(settings_path(name, task), scene=name, kind=scene.kind,
                              task=task, configuration=configuration,
                              task_params=getattr(params.train, task))
               for name, scene in params.scenes.items() for task in TASK_NAMES]
    return "settings: " + ", ".join(f"{d['scene']}/{d['task']} {(d['train'] or {}).get('model')}"
                                    for d in written)


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main())))
