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

One process for both (eskin/steps/report.py, eskin/steps/track.py): the page links each
model to its runs, so the report needs the MLflow store too, and MLflow's import and
store cost seconds a process."""

import sys

from eskin.config.base import load_params
from eskin.config.params import Params
from eskin.errors import TRACK_KEPT, run_friendly
from eskin.steps.report import report_at
from eskin.steps.track import model_runs, track_at


def main() -> str:
    params = load_params(Params)
    print(report_at(params, model_runs), flush=True)
    return track_at(params)


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main()), interrupted=TRACK_KEPT))
