"""MLflow tracking: one run per task execution, grouped under a pipeline run.

The store defaults to SQLite in the project (``mlflow.db``, artifacts in
``mlruns/``; both ignored by git and DVC). Under ``dvc exp run --queue`` a
stage runs in a temporary copy of the repository, so the project is found
through ``DVC_ROOT`` (set by DVC to the parent repository) and every
experiment logs to the same store. ``MLFLOW_TRACKING_URI`` overrides it all.

No training stage talks to MLflow: the publish stage, last in the pipeline, logs one
``dvc repro`` or ``dvc exp run`` in one process (:func:`track_pipeline`). Its pipeline
run is keyed by the DVC experiment name, or, outside ``dvc exp``, by the git commit and
the params; it holds the params the pipeline reads (for ``eskin compare``) and the
headline scores. Under it, one run per task: a task trained by this pipeline logs its
scores, predictions, figures and models, registered with the run's lineage as version
tags (for ``eskin reproduce``); a task DVC reused logs its scores and names the run
that trained it.
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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mlflow  # noqa: E402 - telemetry must be off before import
import pandas as pd  # noqa: E402
from mlflow.entities import Metric, Param  # noqa: E402
from mlflow.models import infer_signature  # noqa: E402
from mlflow.tracking import MlflowClient  # noqa: E402

from eskin.catalog import SCHEMES  # noqa: E402
from eskin.tracking.connection import (  # noqa: E402
    EXPERIMENT,
    connect,
    experiment_id_of,
    naming_the_store,
    project_root,
    ui_url,
)

PIPELINE_TAG = "eskin.pipeline"


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
    experiment's name, or the commit and the params (the sections the pipeline reads)."""
    if dvc_experiment():
        return f"exp:{dvc_experiment()}"
    text = json.dumps(params, sort_keys=True, default=str)
    digest = hashlib.sha256(f"{commit}\n{text}".encode()).hexdigest()[:16]
    return f"repro:{digest}"


def variant_name(key: str) -> str:
    """A pipeline run's name: the DVC experiment's, or for a plain ``dvc repro`` the first
    8 hex digits of its key (commit and params)."""
    return dvc_experiment() or f"repro-{key.split(':', 1)[1][:8]}"


def parent_run(client: MlflowClient, experiment_id: str, key: str,
               tags: Mapping[str, str], params: Mapping[str, Any] | None = None,
               start_time: int | None = None) -> str:
    """The id of the pipeline run keyed ``key``, created on first use.

    It carries the params the pipeline reads, flattened, so that variants can be told
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


def requirements() -> list[str]:
    """A logged model's pip requirements, pinned from the running environment: no
    dependency inference at log time."""
    from importlib.metadata import version
    return [f"{name}=={version(name)}" for name in ("scikit-learn", "numpy", "scipy", "pandas")]


@contextlib.contextmanager
def pinned_environment():
    """MLflow's check, as it logs a model, that the running environment satisfies the
    model's requirements, left out: :func:`requirements` pins them from this environment
    (and MLflow pins itself from its own version), so the check cannot find a mismatch,
    and it cost about 1.2 s a process that logs a model (importlib.metadata reads every
    installed distribution to map modules to packages; issue 55). An MLflow that no
    longer makes the check by this name fails here, not silently slower
    (tests/test_logged_models.py)."""
    from unittest import mock

    import mlflow.utils.environment

    with mock.patch.object(mlflow.utils.environment, "warn_dependency_requirement_mismatches",
                           lambda model_requirements: None):
        yield


# ---------------------------------------------------------------- the publish stage
@dataclass(frozen=True)
class TaskFiles:
    """What the pipeline left of one scene's task: its scores (every scheme, and what
    trained on what), and the files the task run logs."""

    scene: str
    task: str
    scores: dict
    scores_path: Path
    predictions_path: Path | None = None
    model_path: Path | None = None
    record_path: Path | None = None
    features_path: Path | None = None
    figures: tuple[Path, ...] = ()
    hyperparameters: Mapping[str, Any] = field(default_factory=dict)
    cv: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Tracked:
    """What :func:`track_pipeline` logged: the pipeline run, and per task ``trained``
    (a run with its models), ``reused`` (DVC kept the task: a run pointing at the one that
    trained it) or ``present`` (already logged under this pipeline run)."""

    pipeline_run: str
    variant: str
    tasks: dict[str, str]
    url: str

    @property
    def summary(self) -> str:
        counts = {what: sum(1 for v in self.tasks.values() if v == what)
                  for what in ("trained", "reused", "scored", "present")}
        told = ", ".join(f"{n} {what}" for what, n in counts.items() if n)
        return (f"MLflow: pipeline run {self.pipeline_run} ({self.variant}): "
                f"{told or 'nothing new'}\n  {self.url}")


def track_pipeline(*, params: Mapping[str, Any], scenes: list[str], tasks: list[TaskFiles],
                   headline: Mapping[str, Any], page: Path | None = None,
                   log=lambda message: None) -> Tracked:
    """Log one ``dvc repro`` / ``dvc exp run`` to MLflow in one process, from what its
    stages wrote: a pipeline run (keyed by the experiment, or by the commit and
    ``params``, which it holds, with the ``headline`` scores and the report page), and
    under it a run per task: with its models, figures and out-of-fold predictions where
    this pipeline trained it (the times are the train stage's own, from its record), or,
    where DVC reused the task's outputs, a run that names the run that trained it."""
    with naming_the_store("logging the pipeline"), warnings.catch_warnings(), \
            _quiet("mlflow.sklearn"):
        # Both warnings are about choices made here on purpose: the dataset source is
        # a plain local path, and integer node labels never carry missing values.
        warnings.filterwarnings("ignore", message="The specified dataset source can be")
        warnings.filterwarnings("ignore", message="Hint: Inferred schema contains integer")
        return _track_pipeline(params, scenes, tasks, headline, page, log)


def _track_pipeline(params, scenes, tasks, headline, page, log) -> Tracked:
    client = connect()
    experiment_id = experiment_id_of(client, EXPERIMENT)
    settle_stale_runs(client, [experiment_id])
    commit = git_commit(project_root())
    key = pipeline_key(params, commit)
    variant = variant_name(key)
    records = {(t.scene, t.task): _record(t) for t in tasks}
    # This pipeline's own training: a record that names no run yet. A reused task's record
    # names the run that trained it earlier; its times are that run's, not this one's.
    fresh = [r for r in records.values() if r and not r.get("run_id")]
    starts = [r["started"] for r in fresh]
    tags = {"eskin.git_commit": commit, "mlflow.source.git.commit": commit,
            "eskin.dvc_experiment": dvc_experiment(), PIPELINE_TAG: key}
    parent = parent_run(client, experiment_id, key, {**tags, "eskin.scenes": ",".join(scenes)},
                        params, int(1000 * min(starts)) if starts else None)
    present = {(r.data.tags.get("eskin.scene"), r.data.tags.get("eskin.task"),
                r.data.tags.get("eskin.model_md5") or r.data.tags.get("eskin.scores_md5"))
               # a run a killed stage left (FAILED) is logged again, whole
               for r in client.search_runs([experiment_id],
                                           f"tags.`mlflow.parentRunId` = '{parent}' "
                                           "and attributes.status = 'FINISHED'",
                                           max_results=1000)}
    # pid and host: a run left RUNNING by a killed process is settled the next time
    common = {**tags, **process_tags(), "mlflow.parentRunId": parent}
    done: dict[str, str] = {}
    for files in tasks:
        name = f"{files.scene}/{files.task}"
        scores, record = files.scores, records[(files.scene, files.task)]
        if files.model_path is None:  # a scoring task (pairs): its scores only
            md5 = _md5(files.scores_path)
            if (files.scene, files.task, md5) in present:
                done[name] = "present"
                continue
            _log_scores(client, experiment_id, files, md5, variant, common)
            done[name] = "scored"
            continue
        md5 = scores["model_md5"]
        if (files.scene, files.task, md5) in present:
            done[name] = "present"
            continue
        earlier = _trained_run(client, experiment_id, files.scene, files.task, md5)
        if earlier and not (record and not record.get("run_id")):
            log(f"{name}: reused by DVC (trained in run {earlier})")
            _log_reused(client, experiment_id, files, earlier, variant, common)
            done[name] = "reused"
            continue
        log(f"{name}: logging its run, models and figures …")
        run_id = _log_trained(client, experiment_id, files, record, variant, common)
        if record:  # the record now names its run: a later pipeline that reuses the task
            _write_record(files.record_path, {**record, "run_id": run_id})  # points at it
        done[name] = "trained"
    ends = [r["ended"] for r in fresh]
    client.log_batch(parent, metrics=[Metric(k, float(v), int(1000 * time.time()), 0)
                                      for k, v in headline_metrics(headline).items()])
    share_key = headline_view(client, experiment_id, headline)
    if page is not None and Path(page).exists():
        client.log_artifact(parent, str(page))
    if any(what != "present" for what in done.values()) or not done:
        # A pipeline run ends when its last logging did: a repro that logged nothing new
        # (DVC ran the stage again on the same outputs) leaves its duration alone.
        end = max([int(1000 * time.time())] + [int(1000 * e) for e in ends])
        client.set_terminated(parent, end_time=end)
    return Tracked(parent, variant, done, ui_url(experiment_id, view=share_key))


def headline_metrics(headline: Mapping[str, Any]) -> dict[str, float]:
    """A pipeline run's headline scores under names that say their CV scheme, as a task
    run's do: ``conditions.single_force.force.r2`` (the task run's ``conditions.force.r2``)."""
    from eskin.catalog import HEADLINE_SCHEME

    return {k: float(v) for k, v in flatten({HEADLINE_SCHEME: headline}).items()}


# MLflow's shared view state: an experiment tag ``mlflow.sharedViewState.<key>`` holds the
# runs table's state as JSON, and ``?viewStateShareKey=<key>`` opens the table in it (the
# UI's own "Share" button writes the same tag). eskin writes one: the pipeline runs, newest
# first, with every headline score as a column.
SHARED_VIEW_TAG, HEADLINE_VIEW = "mlflow.sharedViewState.", "eskin-headline"


def headline_view(client: MlflowClient, experiment_id: str,
                  headline: Mapping[str, Any]) -> str:
    """Write (or widen) the headline view of the experiment's runs table; its share key."""
    tag = SHARED_VIEW_TAG + HEADLINE_VIEW
    before = client.get_experiment(experiment_id).tags.get(tag)
    columns = []
    if before:
        with contextlib.suppress(ValueError, AttributeError):
            columns = list(json.loads(before).get("selectedColumns", []))
    # Every variant's columns stay: a scene that one variant lacks keeps its column.
    columns += [f"metrics.`{name}`" for name in headline_metrics(headline)
                if f"metrics.`{name}`" not in columns]
    # Wide enough for a whole name (the UI cuts a header at its column's width).
    widths = {"attributes.`Run Name`": 160,
              **{column: 24 + 6 * len(column) for column in columns}}
    state = {"searchFilter": "", "orderByKey": "attributes.start_time", "orderByAsc": False,
             "selectedColumns": ["attributes.`Run Name`", *columns],
             # the UI applies widths to the columns its order names
             "columnOrder": ["attributes.`Run Name`", "runDateAndNestInfo", "duration",
                             *columns], "columnWidths": widths,
             "runsExpanded": {}, "runsPinned": [], "runsHidden": []}
    client.set_experiment_tag(experiment_id, tag, json.dumps(state))
    return HEADLINE_VIEW


def tracked_record(tasks: list[TaskFiles], headline: Mapping[str, Any],
                   params: Mapping[str, Any]) -> dict[str, Any]:
    """What the publish stage logged, by content alone (no run id, time or commit), so
    that the same pipeline outputs give the same file on any machine: its hash in dvc.lock
    does not move when a fresh clone logs them again."""
    text = json.dumps(params, sort_keys=True, default=str)
    return {"params_sha256": hashlib.sha256(text.encode()).hexdigest(),
            "headline": headline_metrics(headline),
            "tasks": {f"{t.scene}/{t.task}": t.scores.get("model_md5") or _md5(t.scores_path)
                      for t in tasks}}


def _md5(path: Path) -> str:
    return hashlib.md5(Path(path).read_bytes()).hexdigest()


def _record(files: TaskFiles) -> dict | None:
    """The train stage's record of this very model (same md5), else None: DVC reused the
    task's outputs, or they came from elsewhere (a pull, another clone)."""
    if files.record_path is None or not Path(files.record_path).exists():
        return None
    record = json.loads(Path(files.record_path).read_text())
    return record if record.get("model_md5") == files.scores.get("model_md5") else None


def _write_record(path: Path, record: dict) -> None:
    Path(path).write_text(json.dumps(record, indent=2, sort_keys=True) + "\n")


def _trained_run(client: MlflowClient, experiment_id: str, scene: str, task: str,
                 md5: str) -> str | None:
    """The first run that trained (not reused) ``scene``/``task``'s model of this md5."""
    found = client.search_runs(
        [experiment_id], f"tags.`eskin.model_md5` = '{md5}' and tags.`eskin.task` = '{task}' "
        f"and tags.`eskin.scene` = '{scene}' and tags.`eskin.trained` != 'reused' "
        "and attributes.status = 'FINISHED'", order_by=["attributes.start_time ASC"],
        max_results=1)
    return found[0].info.run_id if found else None


def task_params(files: TaskFiles) -> dict[str, str]:
    """A task run's params under names that stay the same whichever model it runs
    (``force.model``, ``force.max_iter``), so that runs of different models compare; and
    the CV settings (``cv.folds``; ``eskin reproduce`` reruns the folds from them)."""
    named = {f"{files.task}.model": files.scores.get("model", ""),
             **{f"{files.task}.{k}": v for k, v in flatten(files.hyperparameters).items()},
             **{f"cv.{k}": v for k, v in files.cv.items()}}
    return {k: str(v) for k, v in named.items()}


def _scores_metrics(scores: Mapping[str, Any]) -> dict[str, float]:
    """Every scheme's scores and spreads, ``<scheme>.<target>.<score>``."""
    return {k: float(v) for k, v in flatten({s: scores[s] for s in SCHEMES if s in scores}).items()
            if isinstance(v, (int, float)) and not isinstance(v, bool)}


def _task_tags(files: TaskFiles, common: Mapping[str, str], trained: str) -> dict[str, str]:
    s = files.scores
    schemes = [k for k in SCHEMES if k in s]
    return {**common, "eskin.scene": files.scene, "eskin.task": files.task, "eskin.kind": "task",
            "eskin.model": s.get("model", ""), "eskin.model_md5": s.get("model_md5", ""),
            "eskin.dataset_digest": s.get("dataset_md5", ""),
            "eskin.dataset_rows": str(s.get("dataset_rows", "")),
            "eskin.dataset_source": s.get("source", ""),
            "eskin.cv_schemes": ",".join(schemes), "eskin.trained": trained}


def _log_reused(client, experiment_id, files, earlier, variant, common) -> str:
    """A task DVC reused: its scores, and the run that trained its model."""
    run = client.create_run(
        experiment_id, run_name=f"{files.scene}/{files.task} {files.scores.get('model', '')} "
                                f"@{variant} (reused)",
        tags={**_task_tags(files, common, "reused"), "eskin.reused_from": earlier})
    client.log_batch(run.info.run_id, metrics=[
        Metric(k, v, int(1000 * time.time()), 0) for k, v in _scores_metrics(files.scores).items()],
        params=[Param(k, v) for k, v in task_params(files).items()])
    client.set_terminated(run.info.run_id)
    return run.info.run_id


def _log_scores(client, experiment_id, files, md5, variant, common) -> str:
    """A run that only scores other runs' predictions (two-force pairs)."""
    run = client.create_run(
        experiment_id, run_name=f"{files.scene}/{files.task} @{variant}",
        tags={**common, "eskin.scene": files.scene, "eskin.task": files.task,
              "eskin.kind": "scores", "eskin.scores_md5": md5,
              "eskin.dataset_digest": files.scores.get("dataset_md5", "")})
    client.log_batch(run.info.run_id, metrics=[
        Metric(k, v, int(1000 * time.time()), 0) for k, v in _scores_metrics(files.scores).items()])
    client.set_terminated(run.info.run_id)
    return run.info.run_id


def _log_trained(client, experiment_id, files, record, variant, common) -> str:
    """A task this pipeline trained (``record``: the train stage's own times and per-fold
    scores), or one whose outputs came from elsewhere with no run here (``record`` None):
    params, scores, dataset, predictions, figures, and its models, registered with a
    description (dataset, scores, run)."""
    from eskin.data.schema import dataset_skin, read_dataset
    from eskin.learning.saved import load_models

    s = files.scores
    run = client.create_run(
        experiment_id, start_time=int(1000 * record["started"]) if record else None,
        run_name=f"{files.scene}/{files.task} {s.get('model', '')} @{variant}",
        tags={**_task_tags(files, common, "here" if record else "elsewhere"),
              **({"eskin.features_md5": _md5(files.features_path)}
                 if files.features_path else {})})
    run_id = run.info.run_id
    metrics = _scores_metrics(s)
    if record:
        metrics["wall_seconds"] = float(record["wall_seconds"])
        metrics.update({f"{scheme}.{k}": float(v) for scheme, t in record["timings"].items()
                        for k, v in t.items()})
    now = int(1000 * time.time())
    client.log_batch(run_id, metrics=[Metric(k, v, now, 0) for k, v in metrics.items()],
                     params=[Param(k, v) for k, v in task_params(files).items()])
    frame = read_dataset(files.features_path)
    with mlflow.start_run(run_id=run_id):
        mlflow.log_input(mlflow.data.from_pandas(
            frame.drop(columns=["session", "trial", "seq", "t_ms"], errors="ignore"),
            source=str(files.features_path), targets=None, name=files.scene,
            digest=s.get("dataset_md5", "")), context="training")
        if record:
            for scheme, per_fold in record["per_fold"].items():
                # Per fold as an artifact, not as metrics: the UI's charts and parallel
                # coordinates took a fold's score for the run's.
                mlflow.log_dict(per_fold, f"scores/per_fold_{scheme}.json")
        for scheme, confusion in s.get("confusion", {}).items():
            mlflow.log_dict(confusion, f"confusion/{scheme}.json")
        predictions = pd.read_parquet(files.predictions_path)
        with tempfile.TemporaryDirectory() as scratch:
            for scheme, oof in predictions.groupby("scheme", sort=False):
                path = Path(scratch) / f"oof_{scheme}.parquet"
                oof.drop(columns="scheme").to_parquet(path, index=False)
                mlflow.log_artifact(str(path), artifact_path="predictions")
        for figure in files.figures:
            mlflow.log_artifact(str(figure), artifact_path="figures")
        models = load_models(files.model_path, s["model_md5"])
        example = frame[dataset_skin(files.features_path).channels].head(5)
        lineage = {k: v for k, v in _task_tags(files, {}, "").items()
                   if k not in ("eskin.kind", "eskin.trained")}
        headline = _headline_text(s)
        for target, model in models.items():
            # No input_example: with one, MLflow reloads the saved model and predicts the
            # example to validate it for serving (measured about 1 s a model); the
            # environment is pinned (pip_requirements), the signature names the inputs,
            # and the train stage's export checks the stack's predictions against the models'.
            # What is lost: the example shown on the model's page.
            with pinned_environment():
                info = mlflow.sklearn.log_model(
                    model, name=files.task if target == files.task else f"{files.task}-{target}",
                    signature=infer_signature(example, model.predict(example)),
                    pip_requirements=requirements(), serialization_format="cloudpickle")
            # Registered with the run's lineage: `eskin reproduce` finds the dataset
            # version by these tags and reruns the cross-validation on it.
            name = registered_name(files.scene, files.task, target)
            _ensure_registered_model(client, name)
            client.create_model_version(
                name, source=info.model_uri, run_id=run_id, model_id=info.model_id,
                tags={**lineage, "eskin.target": target,
                      **({"eskin.features_md5": _md5(files.features_path)}
                         if files.features_path else {})},
                await_creation_for=0,
                description=(f"{files.scene}/{files.task}, target {target}: {s.get('model')} "
                             f"on dataset {s.get('dataset_md5', '')[:8]} "
                             f"({s.get('dataset_rows')} rows, {s.get('source', '')}); "
                             f"{headline}; run {run_id}"))
    client.set_terminated(run_id, end_time=int(1000 * record["ended"]) if record else None)
    return run_id


def _headline_text(scores: Mapping[str, Any]) -> str:
    """``conditions CV: force r2 0.941 ± 0.010``: the headline scheme's scores of a task."""
    from eskin.catalog import HEADLINE_METRIC, HEADLINE_SCHEME

    scheme = scores.get(HEADLINE_SCHEME, {})
    parts = [f"{target} {name} {values[name]:.3f} ± {values.get(name + '_std', 0):.3f}"
             for target, values in scheme.items() for name in set(HEADLINE_METRIC.values())
             if isinstance(values, Mapping) and name in values]
    return f"{HEADLINE_SCHEME} CV: " + ", ".join(parts)


def pipeline_tasks(scenes: Mapping[str, Any], train: Any, cv: Mapping[str, Any], *,
                   log=lambda message: None) -> list[TaskFiles]:
    """Every scored task of ``scenes`` (the ``scenes`` section) as its stages left it;
    a task with no scores, or skipped, is left out (and said). ``train``: the ``train``
    section (the hyperparameters each run logs), ``cv``: the ``cv`` section as a dict."""
    from eskin.catalog import (
        FIGURES_DIR,
        SCORED_TASKS,
        TASK_NAMES,
        features_path,
        model_path,
        predictions_path,
        run_record_path,
        scores_path,
    )
    from eskin.data.schema import dataset_skin
    from eskin.evaluation.tasks import get_task
    from eskin.kinds import DATASET_KINDS
    from eskin.learning.choice import chosen_model
    from eskin.reporting import presentation

    found = []
    for scene in scenes:
        for task in SCORED_TASKS:
            path = scores_path(scene, task)
            if not path.exists():
                log(f"{scene}/{task}: no scores ({path}); not logged")
                continue
            scores = json.loads(path.read_text())
            if scores.get("status") not in ("trained", "scored"):
                continue
            if task not in TASK_NAMES:
                found.append(TaskFiles(scene, task, scores, path))
                continue
            kind = DATASET_KINDS[scores["kind"]]
            task_models = getattr(train, task)
            # the skin the features were taken on, as the train step reads it
            _, hyper, _ = chosen_model(task_models, train.configuration, kind.scene_kind,
                                       dataset_skin(features_path(scene)),
                                       get_task(kind.name, task).role)
            figures = tuple(sorted(p for figure in presentation.figures(kind) if figure.task == task
                                   for p in (FIGURES_DIR / scene).glob(f"{figure.id}_*.*")))
            found.append(TaskFiles(scene, task, scores, path, predictions_path(scene, task),
                                   model_path(scene, task), run_record_path(scene, task),
                                   features_path(scene), figures, hyper, cv))
    return found
