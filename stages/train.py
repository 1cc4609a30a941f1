"""DVC stage: features and folds of a scene, and the models its settings name → each
task's scores, predictions, models, and the run's record for the tracking stage (a task
trained from the same inputs and code is kept). ``python -m stages.train <scene> <task>``:
that task alone."""

import sys

from eskin.errors import TASKS_KEPT, run_friendly
from eskin.steps.train import run as main

if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(*sys.argv[1:3])), interrupted=TASKS_KEPT))
