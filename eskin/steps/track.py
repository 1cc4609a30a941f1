"""The pipeline's runs in MLflow (:func:`eskin.tracking.runs.track_pipeline`), logged from
what its stages wrote, and what was logged (``reports/runs/tracked.json``, ignored by
git: a fresh clone, whose store is empty, logs once). The publish stage calls it after
the report (:mod:`eskin.steps.report`), whose page links each model to its runs
(:func:`model_runs`): one process, so MLflow's import and store are paid once."""

from __future__ import annotations

import functools
import json
import sys
from collections.abc import Callable

from eskin.catalog import METRICS, PAGE, TRACKED
from eskin.config.params import Params, pipeline_params
from eskin.tracking import connection, runs


def _log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def model_runs() -> Callable[[str], str] | None:
    """The page's links to each model's runs in MLflow's UI, which are logged next: by the
    experiment they are logged to, found or made here. A store out of reach costs the
    links, not the report."""
    try:
        return functools.partial(connection.model_runs_url, connection.ensure_experiment())
    except connection.TrackingError as err:
        print(f"report: the page's model md5s link nowhere: {err}", file=sys.stderr)
        return None


def track_at(params: Params) -> str:
    """The pipeline run and a run per task logged (a task run already logged for its model
    is not logged again), from the pipeline's files under the working directory; the
    summary line, with the link to the runs."""
    logged = pipeline_params(params)
    tasks = runs.pipeline_tasks(params.scenes, params.train, logged["cv"], log=_log)
    headline = json.loads(METRICS.read_text())
    tracked = runs.track_pipeline(params=logged, scenes=list(logged["scenes"]), tasks=tasks,
                                  headline=headline, page=PAGE, log=_log)
    TRACKED.parent.mkdir(parents=True, exist_ok=True)
    TRACKED.write_text(json.dumps(runs.tracked_record(tasks, headline, logged), indent=2,
                                 sort_keys=True) + "\n")
    return tracked.summary
