"""DVC stage: what the pipeline wrote → MLflow, in one process: the pipeline run (its
params and headline scores) and a run per task, trained here or reused by DVC."""

import json
import sys

from eskin.catalog import METRICS, PAGE
from eskin.config import load_params, pipeline_params
from eskin.errors import run_friendly


def main() -> str:
    from eskin.tracking import runs  # MLflow takes seconds to import

    params = load_params()
    logged = pipeline_params(params)
    tasks = runs.pipeline_tasks(params.scenes, params.train, logged["cv"],
                                log=lambda m: print(m, file=sys.stderr, flush=True))
    return runs.track_pipeline(params=logged, scenes=list(logged["scenes"]), tasks=tasks,
                               headline=json.loads(METRICS.read_text()), page=PAGE,
                               log=lambda m: print(m, file=sys.stderr, flush=True)).summary


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main())))
