"""DVC stage: what the pipeline trained → its views, in one process.

1. The report: a two-contact scene's contacts scored as sets (reports/pairs/), figures,
   plot data, reports/index.html, reports/results.md, the headline scores
   (reports/metrics.json) and DVC's metrics, a file a scene (reports/metrics/). A figure
   whose data and drawing code are unchanged is read from its cache, not drawn again;
   a report written from the same predictions, scores, params and code is kept whole.
2. MLflow: the pipeline run (its params and headline scores) and a run per task, trained
   here or reused by DVC; a task run already logged for its model is not logged again.
   Its output, reports/runs/tracked.json, says what it logged; git ignores it, so a fresh
   clone runs this stage once (its MLflow store is empty), and a second `dvc repro` skips
   it.

One process for both: the page links each model to its runs, so the report needs the
MLflow store too, and MLflow's import and store cost seconds a process."""

import functools
import json
import sys

from eskin.catalog import METRICS, PAGE, TRACKED
from eskin.config.base import load_params
from eskin.config.params import Params, pipeline_params
from eskin.errors import TRACK_KEPT, run_friendly
from eskin.steps.report import report_at
from eskin.tracking import connection, runs


def model_runs():
    """The page's links to each model's runs in MLflow's UI, which are logged next: by the
    experiment they are logged to, found or made here. A store out of reach costs the
    links, not the report."""
    try:
        return functools.partial(connection.model_runs_url, connection.ensure_experiment())
    except connection.TrackingError as err:
        print(f"report: the page's model md5s link nowhere: {err}", file=sys.stderr)
        return None


def track(params: Params) -> str:
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


def main() -> str:
    params = load_params(Params)
    reported = report_at(params, model_runs)
    print(reported, flush=True)
    return track(params)


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main()), interrupted=TRACK_KEPT))
