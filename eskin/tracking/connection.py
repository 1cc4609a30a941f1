"""The project's MLflow store, as every user of it reaches it: the connection, the
experiment, its errors as one line, and the UI's links. Kept apart from the tracking
stage's logging (eskin.tracking.runs), which loads models, so that what only links to
the store (the report's page) does not depend on the models' code.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

# MLflow sets its loggers' level when imported: its INFO lines (the tables it creates in a
# new SQLite store, alembic's migrations) are not the publish stage's output. Warnings
# and errors still show; MLFLOW_LOGGING_LEVEL=INFO brings the rest back.
os.environ.setdefault("MLFLOW_LOGGING_LEVEL", "WARNING")
os.environ.setdefault("MLFLOW_ENABLE_TELEMETRY", "false")
os.environ.setdefault("MLFLOW_DISABLE_TELEMETRY", "true")
os.environ.setdefault("MLFLOW_SUPPRESS_PRINTING_URL_TO_STDOUT", "true")  # stage output: ours
os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
# A tracking server that is gone: three tries over about 7 s, not MLflow's seven over
# minutes; a request that hangs, 60 s.
os.environ.setdefault("MLFLOW_HTTP_REQUEST_MAX_RETRIES", "3")
os.environ.setdefault("MLFLOW_HTTP_REQUEST_BACKOFF_FACTOR", "1")
os.environ.setdefault("MLFLOW_HTTP_REQUEST_TIMEOUT", "60")

import mlflow  # noqa: E402 - telemetry must be off before import
from mlflow.tracking import MlflowClient  # noqa: E402

from eskin.errors import EskinError  # noqa: E402
from eskin.tracking import store  # noqa: E402

EXPERIMENT = "eskin"


class TrackingError(EskinError, RuntimeError):
    """The tracking store failed; the message names it."""


@contextlib.contextmanager
def naming_the_store(what: str):
    """MLflow's (and its HTTP client's) errors as one line that says which store failed."""
    import requests

    try:
        yield
    except (mlflow.exceptions.MlflowException, requests.RequestException, OSError) as err:
        first = (str(err).strip().splitlines() or [type(err).__name__])[0][:300]
        raise TrackingError(f"MLflow tracking at {tracking_uri()} failed while {what}: "
                            f"{first}") from None


def project_root() -> Path:
    return Path(os.environ.get("DVC_ROOT") or Path.cwd()).resolve()


def tracking_uri() -> str:
    return os.environ.get("MLFLOW_TRACKING_URI") or store.own_uri(project_root())


def log_pipeline_command() -> str:
    """The command that fills an empty store, as the workspace stands: `dvc repro`, unless
    its publish stage already ran here (into another store, or one since deleted), when
    DVC would skip it."""
    from eskin.catalog import TRACKED

    if (project_root() / TRACKED).exists():
        return "`dvc repro --force --single-item publish`"
    return "`dvc repro`"


def connect() -> MlflowClient:
    """Point MLflow (its fluent API too) at the project's store; a client on it."""
    mlflow.set_tracking_uri(tracking_uri())
    return MlflowClient()


# MLflow 3's UI opens an experiment in its GenAI view (traces, token usage) unless told
# that the experiment trains models.
EXPERIMENT_KIND, MODEL_TRAINING = "mlflow.experimentKind", "custom_model_development"


def experiment_id_of(client: MlflowClient, name: str) -> str:
    # Not "MLFLOW_TRACKING_URI unset": mlflow.set_tracking_uri (connect) sets it.
    own_store = tracking_uri() == store.own_uri(project_root())
    experiment = (store.own_experiment(client, name, project_root()) if own_store
                  else client.get_experiment_by_name(name))
    if experiment is not None:
        if experiment.tags.get(EXPERIMENT_KIND) != MODEL_TRAINING:  # made by an older eskin
            client.set_experiment_tag(experiment.experiment_id, EXPERIMENT_KIND, MODEL_TRAINING)
        return experiment.experiment_id
    location = store.artifact_root(project_root()) if own_store else None
    try:
        return client.create_experiment(name, artifact_location=location,
                                        tags={EXPERIMENT_KIND: MODEL_TRAINING})
    except mlflow.exceptions.MlflowException:
        # Another stage created it between our lookup and create.
        return client.get_experiment_by_name(name).experiment_id


# MLflow 3's UI opens an experiment in the view the URL names (`workflowType`), else in the
# browser's last choice, GenAI unless changed: `mlflow.experimentKind` does not decide it.
# Links eskin prints name the training view.
TRAINING_VIEW = "workflowType=machine_learning"


def ensure_experiment() -> str:
    """The id of the project's experiment on the tracking store, made (as model training)
    if missing."""
    with naming_the_store("finding the experiment"):
        return experiment_id_of(connect(), EXPERIMENT)


def ui_url(experiment_id: str, run_id: str | None = None, artifacts: bool = False,
           view: str | None = None) -> str:
    """The MLflow UI's page of an experiment (in a shared ``view`` of its runs table, or
    one of its runs, or the run's artifacts), on the tracking server, or on `mlflow ui`'s
    default address for a local store."""
    base = ui_base()
    page = f"#/experiments/{experiment_id}" + (f"/runs/{run_id}" if run_id else "") + (
        "/artifacts" if run_id and artifacts else "")
    if view and not run_id:
        # the runs table's own route: from the experiment's, the UI redirects there and
        # drops the share key
        return f"{base}/{page}/runs?viewStateShareKey={view}&{TRAINING_VIEW}"
    return f"{base}/{page}?{TRAINING_VIEW}"


def ui_base() -> str:
    """The MLflow UI's address: the tracking server's, or `mlflow ui`'s default for a
    local store."""
    uri = tracking_uri()
    return uri.rstrip("/") if uri.startswith(("http://", "https://")) else "http://127.0.0.1:5000"


def model_runs_url(experiment_id: str, md5: str) -> str:
    """The MLflow UI's runs table of the experiment, filtered to the runs of the model
    file of this md5 (tag ``eskin.model_md5``: the run that trained it, and any that
    reused it): a link that needs no run id, for the report page, written before the
    publish stage. Sorted by name, not by date: sorted by date, the UI nests a task run
    under its pipeline run, closed, and the filtered run did not show."""
    from urllib.parse import quote, urlencode

    query = urlencode({"searchFilter": f"tags.`eskin.model_md5` = '{md5}'",
                       "orderByKey": "tags.`mlflow.runName`", "orderByAsc": "true"},
                      quote_via=quote)
    return f"{ui_base()}/#/experiments/{experiment_id}/runs?{query}&{TRAINING_VIEW}"
