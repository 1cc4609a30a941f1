"""MLflow tracking: one run per task execution, grouped under a pipeline run.

The store defaults to SQLite in the project (``mlflow.db``, artifacts in
``mlruns/``; both ignored by git and DVC). Under ``dvc exp run --queue`` a
stage runs in a temporary copy of the repository, so the project is found
through ``DVC_ROOT`` (set by DVC to the parent repository) and every
experiment logs to the same store. ``MLFLOW_TRACKING_URI`` overrides it all.

A pipeline run — all the stages of one ``dvc repro`` or one ``dvc exp run``
— is a parent run keyed by the DVC experiment name, or, outside ``dvc exp``,
by the git commit and the params file; each stage finds its parent by that
key (creating it on first use) and logs its own run under it. The parent
carries the whole params file (for ``eskin compare``); each task run registers
its final models with the run's lineage as version tags (for ``eskin reproduce``).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import socket
import subprocess
import tempfile
import time
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any, NamedTuple

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
import pandas as pd  # noqa: E402
from mlflow.entities import Param  # noqa: E402
from mlflow.models import infer_signature  # noqa: E402
from mlflow.tracking import MlflowClient  # noqa: E402

from eskin.errors import EskinError  # noqa: E402

EXPERIMENT = "eskin"
PIPELINE_TAG = "eskin.pipeline"


class TrackingError(EskinError, RuntimeError):
    """The tracking store failed; the message names it."""


@contextlib.contextmanager
def _naming_the_store(what: str):
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
    return os.environ.get("MLFLOW_TRACKING_URI") or f"sqlite:///{project_root() / 'mlflow.db'}"


def connect() -> MlflowClient:
    """Point MLflow (its fluent API too) at the project's store; a client on it."""
    mlflow.set_tracking_uri(tracking_uri())
    return MlflowClient()


def git_commit(root: Path | None = None) -> str:
    """HEAD of the working copy (empty when not in git)."""
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root or Path.cwd(),
                             capture_output=True, text=True, check=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return ""
    return out.stdout.strip()


def dvc_experiment() -> str:
    return os.environ.get("DVC_EXP_NAME", "")


def pipeline_key(params: Mapping[str, Any], commit: str) -> str:
    """The same for every stage of one ``dvc repro`` / ``dvc exp run``: the DVC
    experiment's name, or the commit and the params (as :func:`logged_params` gives them)."""
    if dvc_experiment():
        return f"exp:{dvc_experiment()}"
    text = json.dumps(params, sort_keys=True, default=str)
    digest = hashlib.sha256(f"{commit}\n{text}".encode()).hexdigest()[:16]
    return f"repro:{digest}"


def logged_params(params: Any | None) -> dict[str, Any]:
    """The whole params file (a :class:`eskin.config.Params`) as the pipeline run logs it:
    as written, keys the file leaves out left out (flattened by :func:`flatten`). Not a
    stage's knobs: read under the trace's proxy without noting them."""
    if params is None:
        return {}
    from eskin.config import untraced

    return untraced(params).model_dump(exclude_unset=True)


# MLflow 3's UI opens an experiment in its GenAI view (traces, token usage) unless told
# that the experiment trains models.
EXPERIMENT_KIND, MODEL_TRAINING = "mlflow.experimentKind", "custom_model_development"


def variant_name(key: str) -> str:
    """A pipeline run's name: the DVC experiment's, or for a plain ``dvc repro`` the first
    8 hex digits of its key (commit and params)."""
    return dvc_experiment() or f"repro-{key.split(':', 1)[1][:8]}"


def _experiment_id(client: MlflowClient, name: str) -> str:
    experiment = client.get_experiment_by_name(name)
    if experiment is not None:
        if experiment.tags.get(EXPERIMENT_KIND) != MODEL_TRAINING:  # made by an older eskin
            client.set_experiment_tag(experiment.experiment_id, EXPERIMENT_KIND, MODEL_TRAINING)
        return experiment.experiment_id
    location = None
    if not os.environ.get("MLFLOW_TRACKING_URI"):
        location = (project_root() / "mlruns").as_uri()
    try:
        return client.create_experiment(name, artifact_location=location,
                                        tags={EXPERIMENT_KIND: MODEL_TRAINING})
    except mlflow.exceptions.MlflowException:
        # Another stage created it between our lookup and create.
        return client.get_experiment_by_name(name).experiment_id


def parent_run(client: MlflowClient, experiment_id: str, key: str,
               tags: Mapping[str, str], params: Mapping[str, Any] | None = None,
               start_time: int | None = None) -> str:
    """The id of the pipeline run keyed ``key``, created on first use.

    It carries the whole params file, flattened, so that variants can be told
    apart by the params that differ (``eskin compare``).
    """
    found = client.search_runs([experiment_id], filter_string=f"tags.`{PIPELINE_TAG}` = '{key}'"
                               " and tags.`eskin.kind` = 'pipeline'", max_results=1)
    if found:
        return found[0].info.run_id
    run = client.create_run(experiment_id, run_name=variant_name(key), start_time=start_time,
                            tags={**tags, PIPELINE_TAG: key, "eskin.kind": "pipeline"})
    entries = [Param(k, str(v)) for k, v in flatten(params or {}).items()]
    for start in range(0, len(entries), 100):  # the REST API takes 100 params per batch
        client.log_batch(run.info.run_id, params=entries[start:start + 100])
    client.set_terminated(run.info.run_id)
    return run.info.run_id


def flatten(mapping: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"a": {"b": 1}}`` → ``{"a.b": 1}``: nested params and metrics as MLflow keys."""
    out: dict[str, Any] = {}
    for key, value in mapping.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(flatten(value, f"{name}."))
        else:
            out[name] = value
    return out


PID_TAG, HOST_TAG = "eskin.pid", "eskin.host"


def process_tags() -> dict[str, str]:
    """Who writes a run: a run left RUNNING by a process that is gone can be told."""
    return {PID_TAG: str(os.getpid()), HOST_TAG: socket.gethostname()}


def settle_stale_runs(client: MlflowClient, experiment_ids: list[str]) -> list[str]:
    """Mark FAILED every RUNNING run whose writing process, on this host, has ended
    (killed mid-logging: nothing could close it). Returns their ids."""
    host = socket.gethostname()
    settled = []
    for run in client.search_runs(experiment_ids, filter_string="attributes.status = 'RUNNING'",
                                  max_results=1000):
        tags = run.data.tags
        if tags.get(HOST_TAG) != host or not tags.get(PID_TAG, "").isdigit():
            continue  # another machine's run: it may well be alive
        pid = int(tags[PID_TAG])
        try:
            os.kill(pid, 0)
            continue  # still running (or the pid was reused: left alone, it is rare)
        except ProcessLookupError:
            pass
        except PermissionError:
            continue
        client.set_tag(run.info.run_id, "eskin.failure",
                       f"process {pid} on {host} ended without closing the run "
                       "(killed); marked FAILED when next seen")
        client.set_terminated(run.info.run_id, status="FAILED")
        settled.append(run.info.run_id)
    return settled


def _pipeline(scene: str, pipeline_params: Any | None, start_time: int | None = None
              ) -> tuple[str, str, str, dict[str, str]]:
    """(experiment id, parent run id, pipeline key, common tags) for a stage's run; a parent
    made now starts at ``start_time`` (ms since the epoch: the stage's start)."""
    client = connect()
    experiment_id = _experiment_id(client, EXPERIMENT)
    settle_stale_runs(client, [experiment_id])
    params = logged_params(pipeline_params)
    key, tags = _pipeline_key_and_tags(params)
    tags["eskin.scene"] = scene
    return (experiment_id, parent_run(client, experiment_id, key, tags, params,
                                      start_time), key, tags)


def _pipeline_key_and_tags(params: Mapping[str, Any]) -> tuple[str, dict[str, str]]:
    """The pipeline run's key (commit and params) and the tags every run of it carries."""
    commit = git_commit(project_root())
    return pipeline_key(params, commit), {
        "eskin.git_commit": commit, "mlflow.source.git.commit": commit,
        "eskin.dvc_experiment": dvc_experiment()}


def _epoch_ms(perf_counter_start: float | None) -> int | None:
    """A ``time.perf_counter()`` reading as milliseconds since the epoch."""
    if perf_counter_start is None:
        return None
    return int(1000 * (time.time() - (time.perf_counter() - perf_counter_start)))


def _extend_parent(client: MlflowClient, parent: str) -> None:
    """The pipeline run ends when its last task run does (runs of parallel stages end in
    any order: the latest end is kept)."""
    now = int(1000 * time.time())
    if (client.get_run(parent).info.end_time or 0) < now:
        client.set_terminated(parent, end_time=now)


def log_task_run(*, scene: str, task: str, params: Mapping[str, Any],
                 pipeline_params: Any | None,
                 results: list, models: Mapping[str, Any], dataset: pd.DataFrame,
                 channels: list[str], dataset_digest: str, dataset_source: str,
                 started: float | None = None,
                 extra_tags: Mapping[str, str] | None = None) -> TrackedRun:
    """Log one task execution and register its models; returns the run id and versions.

    ``results`` are :class:`~eskin.evaluation.crossval.CVResult` per scheme;
    ``models`` maps target name → fitted final model; ``dataset`` is the
    frame that trained them (features and labels), logged as an MLflow input
    whose digest is the DVC md5 of the dataset's Parquet file, and ``channels`` its skin's
    channels (the models' input example); ``started``, the
    step's ``time.perf_counter()`` at its start, gives the metric ``wall_seconds``;
    ``pipeline_params``, the whole :class:`eskin.config.Params`, goes to the pipeline run.
    """
    with _naming_the_store(f"logging {scene}/{task}"):
        return _log_task_run(scene, task, params, pipeline_params, results, models, dataset,
                             channels, dataset_digest, dataset_source, started, extra_tags)


def _log_task_run(scene, task, params, pipeline_params, results, models, dataset, channels,
                  dataset_digest, dataset_source, started, extra_tags) -> TrackedRun:
    experiment_id, parent, key, tags = _pipeline(scene, pipeline_params, _epoch_ms(started))
    run_tags = {**tags, **(extra_tags or {}), **process_tags(), "eskin.task": task,
                "eskin.kind": "task",
                "eskin.cv_schemes": ",".join(r.scheme for r in results),
                "eskin.cv_scheme": results[0].scheme if results else "",
                PIPELINE_TAG: key, "eskin.dataset_digest": dataset_digest}
    with warnings.catch_warnings(), _quiet("mlflow.sklearn"):
        # Both warnings are about choices made here on purpose: the dataset source is
        # a plain local path, and integer node labels never carry missing values.
        warnings.filterwarnings("ignore", message="The specified dataset source can be")
        warnings.filterwarnings("ignore", message="Hint: Inferred schema contains integer")
        tracked = _log_run(experiment_id, parent, scene, task, run_tags, params, results,
                           models, dataset, channels, dataset_digest, dataset_source,
                           started, variant_name(key))
        _extend_parent(MlflowClient(), parent)
        return tracked


class _quiet:
    """Raise a logger's level for a block: MLflow's pickle advice, given on every save.

    Models are pickled by design; eskin loads one only after its file's md5
    matches the one recorded in dvc.lock and in the run (``eskin.learning.saved.load_models``).
    """

    def __init__(self, name: str) -> None:
        self.logger = logging.getLogger(name)

    def __enter__(self) -> None:
        self.level = self.logger.level
        self.logger.setLevel(logging.ERROR)

    def __exit__(self, *exc: object) -> None:
        self.logger.setLevel(self.level)


def _log_run(experiment_id, parent, scene, task, run_tags, params, results, models, dataset,
             channels, dataset_digest, dataset_source, started, variant) -> TrackedRun:
    # Created with the step's start, so that the UI's duration is the training's; named
    # so that Compare tells variants and models apart.
    created = MlflowClient().create_run(
        experiment_id, start_time=_epoch_ms(started),
        run_name=f"{scene}/{task} {run_tags.get('eskin.model', '')} @{variant}",
        tags={**run_tags, "mlflow.parentRunId": parent})
    with mlflow.start_run(run_id=created.info.run_id) as run:
        mlflow.log_params({k: str(v) for k, v in flatten(params).items()})
        mlflow.log_input(mlflow.data.from_pandas(dataset, source=dataset_source,
                                                 targets=None, name=scene,
                                                 digest=dataset_digest),
                         context="training")
        for result in results:
            # Per fold as an artifact, not as metrics: the UI's charts and parallel
            # coordinates took a fold's score for the run's.
            mlflow.log_dict(result.per_fold, f"scores/per_fold_{result.scheme}.json")
            mlflow.log_metrics(flatten({result.scheme: result.summary}))
            mlflow.log_metrics({f"{result.scheme}.fit_seconds": result.fit_seconds,
                                f"{result.scheme}.predict_seconds": result.predict_seconds})
        with tempfile.TemporaryDirectory() as scratch:
            for result in results:
                path = Path(scratch) / f"oof_{result.scheme}.parquet"
                result.predictions.to_parquet(path, index=False)
                mlflow.log_artifact(str(path), artifact_path="predictions")
                if result.confusion:
                    mlflow.log_dict(result.confusion, f"confusion/{result.scheme}.json")
        example = dataset[channels].head(5)
        client = MlflowClient()
        lineage = {k: v for k, v in run_tags.items()
                   if k.startswith("eskin.") and k not in ("eskin.kind", "eskin.cv_scheme")}
        registered = []
        for target, model in models.items():
            info = mlflow.sklearn.log_model(
                model, name=task if target == task else f"{task}-{target}",
                input_example=example,
                signature=infer_signature(example, model.predict(example)),
                pip_requirements=_requirements(), serialization_format="cloudpickle")
            # Registered with the run's lineage: `eskin reproduce` finds the dataset
            # version by these tags and reruns the cross-validation on it.
            name = registered_name(scene, task, target)
            _ensure_registered_model(client, name)
            version = client.create_model_version(
                name, source=info.model_uri, run_id=run.info.run_id, model_id=info.model_id,
                tags={**lineage, "eskin.target": target}, await_creation_for=0,
                description=f"{scene}/{task}, target {target}: {run_tags.get('eskin.model')}")
            registered.append(f"{name} v{version.version}")
        if started is not None:
            mlflow.log_metric("wall_seconds", time.perf_counter() - started)
        return TrackedRun(run.info.run_id, registered)


class TrackedRun(NamedTuple):
    run_id: str
    registered: list[str]   # "<registered model> v<version>" per target


def _ensure_registered_model(client: MlflowClient, name: str) -> None:
    try:
        client.create_registered_model(name)
    except mlflow.exceptions.MlflowException as err:
        # Already there: registered by an earlier run, or by a parallel one just now.
        if err.error_code not in ("RESOURCE_ALREADY_EXISTS", "ALREADY_EXISTS"):
            raise


def registered_name(scene: str, task: str, target: str) -> str:
    """The model registry's name for a target's model: ``single_force.force``,
    ``single_force.localise.x``."""
    return f"{scene}.{task}" if target == task else f"{scene}.{task}.{target}"


def _requirements() -> list[str]:
    """Pinned from the running environment: no dependency inference at log time."""
    from importlib.metadata import version
    return [f"{name}=={version(name)}" for name in ("scikit-learn", "numpy", "scipy", "pandas")]


# MLflow 3's UI opens an experiment in the view the URL names (`workflowType`), else in the
# browser's last choice, GenAI unless changed: `mlflow.experimentKind` does not decide it.
# Links eskin prints name the training view.
TRAINING_VIEW = "workflowType=machine_learning"


def ensure_experiment() -> str:
    """The id of the project's experiment on the tracking store, made (as model training)
    if missing."""
    with _naming_the_store("finding the experiment"):
        return _experiment_id(connect(), EXPERIMENT)


def ui_url(experiment_id: str, run_id: str | None = None, artifacts: bool = False) -> str:
    """The MLflow UI's page of an experiment (or one of its runs, or the run's artifacts),
    on the tracking server, or on `mlflow ui`'s default address for a local store."""
    uri = tracking_uri()
    base = uri.rstrip("/") if uri.startswith(("http://", "https://")) else "http://127.0.0.1:5000"
    page = f"#/experiments/{experiment_id}" + (f"/runs/{run_id}" if run_id else "") + (
        "/artifacts" if run_id and artifacts else "")
    return f"{base}/{page}?{TRAINING_VIEW}"


def log_report(*, figures_dir: Path, page_path: Path, pipeline_params: Any | None) -> str:
    """The report's figures (PNG and SVG, under ``figures/<scene>/``) and page as artifacts
    of the pipeline run the training stages logged under; the UI's page of them."""
    with _naming_the_store("logging the report's figures"):
        client = connect()
        experiment_id = _experiment_id(client, EXPERIMENT)
        params = logged_params(pipeline_params)
        key, tags = _pipeline_key_and_tags(params)
        parent = parent_run(client, experiment_id, key, tags, params)
        client.log_artifacts(parent, str(figures_dir), "figures")
        client.log_artifact(parent, str(page_path))
        return ui_url(experiment_id, parent, artifacts=True)


def log_scores_run(*, scene: str, task: str, scores: Mapping[str, Any],
                   pipeline_params: Any | None, dataset_digest: str) -> str:
    """Log a run that only scores other runs' predictions (e.g. two-force pairs)."""
    with _naming_the_store(f"logging {scene}/{task}"):
        return _log_scores_run(scene, task, scores, pipeline_params, dataset_digest)


def _log_scores_run(scene, task, scores, pipeline_params, dataset_digest) -> str:
    experiment_id, parent, key, tags = _pipeline(scene, pipeline_params)
    with mlflow.start_run(experiment_id=experiment_id,
                          run_name=f"{scene}/{task} @{variant_name(key)}", parent_run_id=parent,
                          tags={**tags, "eskin.task": task, "eskin.kind": "scores",
                                PIPELINE_TAG: key, "eskin.dataset_digest": dataset_digest}) as run:
        mlflow.log_metrics({k: v for k, v in flatten(scores).items()
                            if isinstance(v, (int, float))})
    _extend_parent(MlflowClient(), parent)
    return run.info.run_id
