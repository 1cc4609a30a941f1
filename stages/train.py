"""DVC stage: features and folds of a scene, and the model its settings name → one task's
scores, predictions, models, and the run's record for the tracking stage."""

import sys

from eskin.errors import run_friendly
from eskin.steps.train import run as main

if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(sys.argv[1], sys.argv[2]))))
