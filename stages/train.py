"""DVC stage: features of a scene → one task's metrics, predictions, models and MLflow run."""

import sys

from eskin.catalog import FEATURES_DIR, task_outputs
from eskin.config import DEFAULT_PARAMS, load_params
from eskin.errors import run_friendly
from eskin.learning import train

if __name__ == "__main__":
    scene, task = sys.argv[1], sys.argv[2]
    sys.exit(run_friendly(lambda: print(train.train(
        load_params(), scene, task, FEATURES_DIR, params_text=DEFAULT_PARAMS.read_text(),
        **task_outputs(scene, task)))))
