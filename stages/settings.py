"""DVC stage: params.yaml's train section → reports/settings/<scene>/<task>.json, the model
and hyperparameters each scene's task trains, so that each training stage depends on its
own settings, not on a section shared by every kind of scene."""

import sys

from eskin.errors import run_friendly
from eskin.steps.settings import run as main

if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main())))
