"""DVC stage: what the pipeline wrote → MLflow, in one process: the pipeline run (its
params and headline scores) and a run per task, trained here or reused by DVC. Its
output, reports/runs/tracked.json, says what it logged; git ignores it, so a fresh clone
runs this stage once (its MLflow store is empty), and a second `dvc repro` skips it."""

import json
import sys

from eskin.catalog import METRICS, PAGE, TRACKED
from eskin.config.base import load_params
from eskin.config.params import Params, pipeline_params
from eskin.errors import TRACK_KEPT, run_friendly


def main() -> str:
    from eskin.tracking import runs  # MLflow takes seconds to import

    params = load_params(Params)
    logged = pipeline_params(params)
    tasks = runs.pipeline_tasks(params.scenes, params.train, logged["cv"],
                                log=lambda m: print(m, file=sys.stderr, flush=True))
    headline = json.loads(METRICS.read_text())
    tracked = runs.track_pipeline(params=logged, scenes=list(logged["scenes"]), tasks=tasks,
                                  headline=headline, page=PAGE,
                                  log=lambda m: print(m, file=sys.stderr, flush=True))
    TRACKED.parent.mkdir(parents=True, exist_ok=True)
    TRACKED.write_text(json.dumps(runs.tracked_record(tasks, headline, logged), indent=2,
                                  sort_keys=True) + "\n")
    return tracked.summary


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main()), interrupted=TRACK_KEPT))
