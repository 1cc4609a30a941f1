"""Registered models and their lineage: load one, and reproduce its run on its dataset.

Every training run registers its final models (``eskin.tracking.runs.registered_name``)
with the run's lineage as version tags: the DVC md5 of the dataset and of the
features file it was trained on, the git commit, the DVC experiment. From those
alone, ``reproduce`` finds the features file and the model file in DVC's cache
(or the workspace, if it still is that version; either way its md5 is
checked, the model's before it is unpickled), reruns the run's
cross-validation with the model's estimator and compares the out-of-fold
predictions with the ones the run logged.

``promote`` gives an alias to every model of one pipeline run's stack of a scene (the
models it trained, and, for a task DVC reused, the ones the run that trained it
registered); ``stack_from_registry`` loads the stack an alias names, for ``eskin live``.
"""

from __future__ import annotations

import difflib
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from eskin.catalog import (
    HEADLINE_METRIC,
    HEADLINE_SCHEME,
    TASK_NAMES,
    features_path,
    model_path,
    processed_path,
)
from eskin.data.schema import dataset_kind, dataset_skin, md5_file, read_dataset, read_metadata
from eskin.deploy.stack import (
    SkinStack,
    StackError,
    featurizer_for,
    locked_md5s,
    rest_readings,
)
from eskin.evaluation.crossval import cross_validate
from eskin.evaluation.folds import applicable_schemes, assign_folds
from eskin.evaluation.tasks import get_task
from eskin.learning.saved import load_models
from eskin.tracking.compare import NoRunsError, dvc_cache_path, parse_param


def model_version(client, name: str, version: str | None = None):
    """The registry's entry ``name`` at ``version`` (default: the newest); a name it lacks
    is one line with the closest it has, for a typo, and all of them."""
    import mlflow

    known = sorted(m.name for m in client.search_registered_models(max_results=1000))
    if name not in known:
        close = difflib.get_close_matches(name, known, n=1)
        hint = f"; did you mean {close[0]}?" if close else ""
        raise NoRunsError(f"no registered model {name!r}{hint} "
                          f"(registered: {', '.join(known) or 'none'})")
    try:
        if version is not None:
            return client.get_model_version(name, str(version))
        versions = client.search_model_versions(f"name = '{name}'")
    except mlflow.exceptions.MlflowException as err:
        first = (str(err).strip().splitlines() or [type(err).__name__])[0]
        raise NoRunsError(f"no version {version} of registered model {name!r}: {first}") \
            from err
    if not versions:
        raise NoRunsError(f"registered model {name!r} has no version")
    return max(versions, key=lambda v: int(v.version))


def versioned_file(root: Path, workspace: Path, md5: str, what: str) -> Path:
    """The file of this md5: ``workspace`` (relative to ``root``) if it matches, else
    DVC's cache."""
    path = Path(root) / workspace
    if path.exists() and md5_file(path) == md5:
        return path
    cached = dvc_cache_path(root, md5)
    if cached is None:
        raise NoRunsError(f"{what} version {md5} is neither in the workspace ({workspace}) "
                          "nor in DVC's cache: check out the run's commit and `dvc pull`")
    return cached


def reproduce(name: str, version: str | None = None, *, root: Path = Path("."),
              log=lambda message: None) -> dict[str, Any]:
    """Rerun a registered model's cross-validation on its dataset version; compare.

    Folds run as the run ran them (its ``cv.n_jobs``) on this machine's joblib backend.
    ``log`` is told each scheme as it starts and ends (with its time); the folds show as a
    progress bar on stderr in between.
    """
    import mlflow

    from eskin.tracking import connection

    client = connection.connect()
    entry = model_version(client, name, version)
    tags = entry.tags
    scene, task_name, target = tags["eskin.scene"], tags["eskin.task"], tags["eskin.target"]
    run = client.get_run(entry.run_id)
    path = versioned_file(root, features_path(scene),
                          tags["eskin.features_md5"], f"features of {scene}")
    frame, kind, skin = read_dataset(path), dataset_kind(path).name, dataset_skin(path)
    task = get_task(kind, task_name)
    # The model is the DVC-tracked file whose md5 the run recorded (eskin.model_md5, as in
    # dvc.lock), unpickled only after that md5 is checked: a pickle runs code when loaded.
    model_md5 = tags["eskin.model_md5"]
    saved = versioned_file(root, model_path(scene, task_name), model_md5, f"model {name}")
    model = load_models(saved, model_md5)[target]
    params = run.data.params
    # As the folds step drew them: cv.schemes less any the data do not allow.
    schemes = applicable_schemes(frame, kind, parse_param(params["cv.schemes"]))
    out: dict[str, Any] = {"model": name, "version": entry.version, "run": entry.run_id,
                           "features": str(path), "features md5": tags["eskin.features_md5"],
                           "estimator": type(model).__name__, "schemes": {}}
    n_jobs = int(parse_param(params.get("cv.n_jobs", "1")))
    for number, scheme in enumerate(schemes, 1):
        log(f"{name} v{entry.version}: {scheme} cross-validation ({number} of {len(schemes)}), "
            f"{params['cv.folds']} folds, {len(frame)} rows …")
        started = time.perf_counter()
        folds = assign_folds(frame, kind, scheme, int(params["cv.folds"]), int(params["cv.seed"]),
                             skin=skin)
        redone = cross_validate(task, frame, folds, model, scheme, skin, n_jobs=n_jobs,
                                progress=f"{name} {scheme} CV").predictions
        logged = pd.read_parquet(mlflow.artifacts.download_artifacts(
            run_id=entry.run_id, artifact_path=f"predictions/oof_{scheme}.parquet"))
        column = f"{target}_pred"
        a = logged[column].to_numpy(dtype=float)
        b = redone[column].to_numpy(dtype=float)
        out["schemes"][scheme] = {"rows": len(a), "identical": int(np.sum(a == b)),
                                  "max_abs_difference": float(np.max(np.abs(a - b)))
                                  if len(a) == len(b) and len(a) else float("nan")}
        log(f"{name} v{entry.version}: {scheme} cross-validation done in "
            f"{time.perf_counter() - started:.0f} s, {out['schemes'][scheme]['identical']}/"
            f"{len(a)} predictions identical")
    out["reproduced"] = all(s["identical"] == s["rows"] for s in out["schemes"].values())
    return out


def render_reproduction(result: dict[str, Any]) -> str:
    lines = [f"{result['model']} version {result['version']} ({result['estimator']}), "
             f"run {result['run']}",
             f"  dataset: features {result['features md5']} ({result['features']})"]
    for scheme, s in result["schemes"].items():
        lines.append(f"  {scheme}: {s['identical']}/{s['rows']} out-of-fold predictions "
                     f"identical (largest difference {s['max_abs_difference']:.3g})")
    lines.append("  reproduced" if result["reproduced"] else "  NOT reproduced")
    return "\n".join(lines) + "\n"


def scene_models(client, scene: str) -> list:
    """The registered models of ``scene`` (``single_force.force``, ``single_force.localise.x``)."""
    # LIKE's "_" matches any character, and scene names have them: the prefix decides.
    return [model for model in client.search_registered_models(f"name LIKE '{scene}.%'")
            if model.name.startswith(f"{scene}.")]


def one_features_version(versions, scene: str, what: str, fix: str) -> str:
    """The features md5 every one of ``versions`` was trained on; a stack of models
    trained on different features versions is refused (``fix``: what to do instead)."""
    features_md5 = {v.tags.get("eskin.features_md5") for v in versions}
    if len(features_md5) != 1:
        raise StackError(f"{what} of {scene} were trained on different features versions "
                         f"({', '.join(sorted(map(str, features_md5)))}): {fix}")
    return features_md5.pop()


def stack_from_registry(scene: str, alias: str, root: Path = Path("."),
                        log=lambda message: None) -> SkinStack:
    """The stack whose task models carry the MLflow alias ``alias`` (``eskin promote``
    sets it on a whole stack). Each task's file is found by the md5 its version
    recorded, in the workspace or DVC's cache, and checked before it is loaded, as
    ``eskin reproduce`` does; all must come from the same features version. ``log`` is
    told which versions these are."""
    from eskin.tracking import connection

    client = connection.connect()
    versions = [client.get_model_version_by_alias(model.name, alias)
                for model in scene_models(client, scene) if alias in (model.aliases or {})]
    by_task = {v.tags.get("eskin.task"): v for v in versions}
    if not by_task:
        raise StackError(f"no registered model of scene {scene!r} has the alias {alias!r}: "
                         f"set it on a stack with `eskin promote {scene} --alias {alias}`")
    features = versioned_file(root, features_path(scene),
                              one_features_version(
                                  by_task.values(), scene, f"the {alias!r} models",
                                  f"give the alias to one stack (`eskin promote {scene}`)"),
                              f"features of {scene}")
    log(f"registry @{alias}: " + ", ".join(f"{v.name} v{v.version}"
                                           for v in sorted(versions, key=lambda v: v.name)))
    meta = read_metadata(features)
    skin = dataset_skin(features)
    models, skipped = {}, {}
    for task in TASK_NAMES:
        version = by_task.get(task)
        if version is None:
            skipped[task] = f"no {task} model has the alias {alias!r}"
            continue
        md5 = version.tags["eskin.model_md5"]
        models[task] = load_models(versioned_file(root, model_path(scene, task), md5,
                                                  f"{version.name} v{version.version}"), md5)
    processed = versioned_file(root, processed_path(scene), meta["dataset"]["md5"],
                               f"dataset of {scene}")
    return SkinStack(scene, dataset_kind(features).name, skin,
                     featurizer_for(scene, meta, features, skin, root),
                     models, skipped, meta.get("device"),
                     rest_readings(pd.read_parquet(processed), skin))


# ---------------------------------------------------------------- promote
@dataclass(frozen=True)
class PromotedModel:
    """One model version an alias now names, and the task run of the pipeline it came from."""

    name: str
    version: str
    run_id: str        # the run that trained and registered it
    trained: str       # the pipeline's task run: here | elsewhere | reused
    headline: str      # e.g. "conditions CV: force r2 0.941 ± 0.010"


@dataclass(frozen=True)
class Downgrade:
    """A model that took an alias from a version of it that scores better."""

    name: str
    version: str
    replaced: str      # the version that held the alias
    score: str         # e.g. "force r2", under the headline scheme
    new: float
    old: float


@dataclass(frozen=True)
class Promotion:
    scene: str
    alias: str
    pipeline_run: str
    variant: str
    models: tuple[PromotedModel, ...]
    unset: tuple[str, ...]  # models of the scene the alias was taken from: not in this stack
    worse: tuple[Downgrade, ...] = ()  # models that score worse than the version they replaced


def promote(scene: str, alias: str = "champion", *, variant: str | None = None,
            run_id: str | None = None, root: Path = Path(".")) -> Promotion:
    """Give ``alias`` to every registered model of ``scene``'s stack in one pipeline run,
    and take it from the scene's other models, so that ``stack_from_registry(scene,
    alias)`` loads exactly that stack.

    The pipeline run is the one of ``run_id``, else the newest named ``variant`` (a DVC
    experiment's name, or ``repro-…``: the names ``eskin compare`` shows), else the one
    whose task runs logged the models ``dvc.lock`` records (the workspace's stack, which
    ``eskin live`` runs without an alias). A task DVC reused in that run brings the
    versions the run named by ``eskin.reused_from`` registered."""
    from eskin.tracking import connection

    with connection.naming_the_store(f"promoting {scene}'s models"):
        client = connection.connect()
        experiment = client.get_experiment_by_name(connection.EXPERIMENT)
        if experiment is None:
            raise NoRunsError(f"no MLflow experiment {connection.EXPERIMENT!r} at "
                              f"{connection.tracking_uri()}: run "
                              f"{connection.log_pipeline_command()} to log one")
        ids = [experiment.experiment_id]
        if run_id:
            pipeline = _given_pipeline_run(client, ids, run_id)
        elif variant:
            pipeline = _named_pipeline_run(client, ids, variant)
        else:
            pipeline = _workspace_pipeline_run(client, ids, scene, root)
        stack = _stack_versions(client, ids, pipeline, scene)
        one_features_version([v for v, _ in stack], scene,
                             f"the models of pipeline run {pipeline.info.run_id}",
                             "promote a pipeline run that trained them on one "
                             "(`dvc repro` retrains what its features changed)")
        chosen = {v.name for v, _ in stack}
        worse = _downgrades(client, scene, alias, [v for v, _ in stack])
        for version, _ in stack:
            client.set_registered_model_alias(version.name, alias, version.version)
        unset = tuple(sorted(model.name for model in scene_models(client, scene)
                             if alias in (model.aliases or {}) and model.name not in chosen))
        for name in unset:
            client.delete_registered_model_alias(name, alias)
        models = tuple(PromotedModel(version.name, version.version, version.run_id,
                                     task_run.data.tags.get("eskin.trained", ""),
                                     _headline(client.get_run(version.run_id).data.metrics,
                                               version.tags.get("eskin.target", "")))
                       for version, task_run in stack)
    return Promotion(scene, alias, pipeline.info.run_id, pipeline.info.run_name, models, unset,
                     worse)


def render_promotion(promotion: Promotion) -> str:
    lines = [f"{promotion.scene}: alias {promotion.alias!r} on the stack of pipeline run "
             f"{promotion.pipeline_run} ({promotion.variant})"]
    width = max(len(f"{m.name} v{m.version}") for m in promotion.models)
    for m in promotion.models:
        how = "reused" if m.trained == "reused" else f"trained {m.trained}"
        lines.append(f"  {f'{m.name} v{m.version}':<{width}}  run {m.run_id} ({how})  "
                     f"{m.headline}")
    lines += [f"  {name}: alias {promotion.alias!r} removed (not in this stack)"
              for name in promotion.unset]
    lines.append(f"`eskin live {promotion.scene} --alias {promotion.alias}` runs it")
    return "\n".join(lines) + "\n"


def render_downgrades(promotion: Promotion) -> str | None:
    """One line, if the alias went to models that score worse than the versions that held
    it: each with both headline scores."""
    if not promotion.worse:
        return None
    told = "; ".join(f"{d.name} v{d.version} {d.score} {d.new:.3f} against v{d.replaced}'s "
                     f"{d.old:.3f}" for d in promotion.worse)
    return (f"eskin: warning: {promotion.scene}'s {promotion.alias!r} went to models that "
            f"score worse than the ones that held it ({HEADLINE_SCHEME} CV): {told}")


def _downgrades(client, scene: str, alias: str, stack: list) -> tuple[Downgrade, ...]:
    """The versions of ``stack`` that score worse, under the headline scheme, than the
    version of the same model that holds ``alias`` now (r2 and accuracy: higher is better)."""
    holders = {model.name: model.aliases[alias] for model in scene_models(client, scene)
               if alias in (model.aliases or {})}
    worse = []
    for version in stack:
        held = holders.get(version.name)
        if held is None or str(held) == str(version.version):
            continue
        target = version.tags.get("eskin.target", "")
        new = _headline_score(client.get_run(version.run_id).data.metrics, target)
        old = _headline_score(client.get_run(client.get_model_version(
            version.name, str(held)).run_id).data.metrics, target)
        if new is not None and old is not None and new[1] < old[1]:
            worse.append(Downgrade(version.name, str(version.version), str(held),
                                   f"{target} {new[0]}", new[1], old[1]))
    return tuple(worse)


def _headline_score(metrics: dict[str, float], target: str) -> tuple[str, float] | None:
    """(score name, value): a target's headline score in its run, if it logged one."""
    for name in dict.fromkeys(HEADLINE_METRIC.values()):
        key = f"{HEADLINE_SCHEME}.{target}.{name}"
        if key in metrics:
            return name, metrics[key]
    return None


def _headline(metrics: dict[str, float], target: str) -> str:
    """``conditions CV: force r2 0.941 ± 0.010``: a target's headline score in its run."""
    found = _headline_score(metrics, target)
    if found is None:
        return f"{HEADLINE_SCHEME} CV: no score of {target} in its run"
    name, value = found
    spread = metrics.get(f"{HEADLINE_SCHEME}.{target}.{name}_std", 0.0)
    return f"{HEADLINE_SCHEME} CV: {target} {name} {value:.3f} ± {spread:.3f}"


PIPELINE_RUNS = "tags.`eskin.kind` = 'pipeline'"


def _variants(client, ids: list[str]) -> str:
    """The pipeline runs' names, newest first: what ``--experiment`` takes."""
    found = client.search_runs(ids, PIPELINE_RUNS, order_by=["attributes.start_time DESC"],
                               max_results=1000)
    names = list(dict.fromkeys(run.info.run_name for run in found))
    return ", ".join(names[:12] + (["…"] if len(names) > 12 else [])) or "none"


def _given_pipeline_run(client, ids: list[str], run_id: str):
    import mlflow

    try:
        run = client.get_run(run_id)
    except mlflow.exceptions.MlflowException as err:
        if err.error_code not in ("RESOURCE_DOES_NOT_EXIST", "INVALID_PARAMETER_VALUE"):
            raise  # the store failed: said as such by the caller
        run = None
    if run is None or run.info.experiment_id not in ids:
        raise NoRunsError(f"no run {run_id} among eskin's runs; its pipeline runs are "
                          f"named: {_variants(client, ids)}")
    tags = run.data.tags
    if tags.get("eskin.kind") != "pipeline":
        raise NoRunsError(f"run {run_id} is a {tags.get('eskin.kind', 'non-eskin')} run "
                          f"({tags.get('eskin.scene', '?')}/{tags.get('eskin.task', '?')}), "
                          f"not a pipeline run: give its pipeline run, --run "
                          f"{tags.get('mlflow.parentRunId', '<id>')}")
    return run


def _named_pipeline_run(client, ids: list[str], variant: str):
    found = client.search_runs(ids, f"{PIPELINE_RUNS} and attributes.run_name = '{variant}'",
                               order_by=["attributes.start_time DESC"], max_results=1)
    if not found:
        raise NoRunsError(f"no pipeline run named {variant!r}; eskin's pipeline runs are "
                          f"named: {_variants(client, ids)}")
    return found[0]


def _task_runs(client, ids: list[str], filter_string: str) -> list:
    return client.search_runs(ids, f"tags.`eskin.kind` = 'task' and {filter_string}",
                              order_by=["attributes.start_time DESC"], max_results=1000)


def _workspace_pipeline_run(client, ids: list[str], scene: str, root: Path):
    """The newest pipeline run whose task runs of ``scene`` logged exactly the models
    ``dvc.lock`` records."""
    locked = locked_md5s(Path(root))
    wanted = {task: locked[model_path(scene, task).as_posix()] for task in TASK_NAMES
              if model_path(scene, task).as_posix() in locked}
    if not wanted:
        scenes = sorted({Path(path).parent.name for path in locked
                         if path.startswith("models/") and path.endswith(".joblib")})
        raise NoRunsError(f"dvc.lock records no model of scene {scene!r}; it has models of: "
                          f"{', '.join(scenes) or 'none'}")
    parents = {run.data.tags.get("mlflow.parentRunId")
               for task, md5 in wanted.items()
               for run in _task_runs(client, ids, f"tags.`eskin.scene` = '{scene}' and "
                                     f"tags.`eskin.task` = '{task}' and "
                                     f"tags.`eskin.model_md5` = '{md5}'")}
    pipelines = sorted((client.get_run(p) for p in parents if p),
                       key=lambda run: run.info.start_time or 0, reverse=True)
    for pipeline in pipelines:
        logged = _latest_task_runs(client, ids, pipeline.info.run_id, scene)
        if all(run.data.tags.get("eskin.model_md5") == wanted.get(task)
               for task, run in logged.items()):
            return pipeline
    from eskin.tracking import connection

    raise NoRunsError(f"no pipeline run logged the {scene} models dvc.lock records: run "
                      f"{connection.log_pipeline_command()} (its publish stage logs them), or name "
                      "one with "
                      f"--experiment ({_variants(client, ids)}) or --run")


def _latest_task_runs(client, ids: list[str], pipeline_id: str, scene: str) -> dict:
    """task → the newest task run of ``scene`` under the pipeline run (one pipeline key
    logged twice, with a task retrained in between, has two)."""
    latest: dict = {}
    for run in _task_runs(client, ids, f"tags.`mlflow.parentRunId` = '{pipeline_id}' and "
                          f"tags.`eskin.scene` = '{scene}'"):
        latest.setdefault(run.data.tags.get("eskin.task"), run)  # newest first
    return latest


def _stack_versions(client, ids: list[str], pipeline, scene: str) -> list:
    """(model version, the pipeline's task run) of every model of ``scene``'s stack in the
    pipeline run: a task it trained brings the versions its run registered, a reused one
    those of the run that trained it (``eskin.reused_from``)."""
    from eskin.tracking.runs import registered_name

    logged = _latest_task_runs(client, ids, pipeline.info.run_id, scene)
    if not logged:
        raise NoRunsError(f"pipeline run {pipeline.info.run_id} ({pipeline.info.run_name}) "
                          f"logged no task of scene {scene!r}; its scenes: "
                          f"{pipeline.data.tags.get('eskin.scenes', 'none')}")
    stack = []
    for task in sorted(logged, key=lambda t: TASK_NAMES.index(t) if t in TASK_NAMES else 99):
        task_run = logged[task]
        tags = task_run.data.tags
        trained_by = (tags.get("eskin.reused_from") if tags.get("eskin.trained") == "reused"
                      else task_run.info.run_id)
        # The names the run registered its models under (a copy elsewhere shares the run).
        versions = [v for v in client.search_model_versions(f"run_id = '{trained_by}'")
                    if v.name == registered_name(scene, task, v.tags.get("eskin.target", ""))
                    and v.tags.get("eskin.model_md5") == tags.get("eskin.model_md5")]
        if not versions:
            raise NoRunsError(f"run {trained_by} ({scene}/{task}, model "
                              f"{tags.get('eskin.model_md5')}) registered no model version: "
                              "nothing of it to promote")
        stack += [(v, task_run) for v in sorted(versions, key=lambda v: v.name)]
    return stack
