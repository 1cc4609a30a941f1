"""Registered models and their lineage: load one, and reproduce its run on its dataset.

Every training run registers its final models (``eskin.tracking.runs.registered_name``)
with the run's lineage as version tags: the DVC md5 of the dataset and of the
features file it was trained on, the git commit, the DVC experiment. From those
alone, ``reproduce`` finds the features file and the model file in DVC's cache
(or the workspace, if it still is that version; either way its md5 is
checked, the model's before it is unpickled), reruns the run's
cross-validation with the model's estimator and compares the out-of-fold
predictions with the ones the run logged.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from eskin.catalog import TASK_NAMES, features_path, model_path, processed_path
from eskin.data.schema import dataset_kind, dataset_skin, md5_file, read_dataset, read_metadata
from eskin.deploy.stack import SkinStack, StackError, featurizer_for, rest_reading
from eskin.evaluation.crossval import cross_validate
from eskin.evaluation.folds import assign_folds
from eskin.learning.saved import load_models
from eskin.learning.tasks import get_task
from eskin.tracking.compare import NoRunsError, dvc_cache_path, parse_param


def model_version(client, name: str, version: str | None = None):
    """The registry's entry ``name`` at ``version`` (default: the newest)."""
    import mlflow

    try:
        if version is not None:
            return client.get_model_version(name, str(version))
        versions = client.search_model_versions(f"name = '{name}'")
    except mlflow.exceptions.MlflowException as err:
        raise NoRunsError(f"no registered model {name!r} (version {version}): {err}") from err
    if not versions:
        known = sorted(m.name for m in client.search_registered_models())
        raise NoRunsError(f"no registered model {name!r}; registered: {', '.join(known) or 'none'}")
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
    """
    import mlflow

    from eskin.tracking import runs

    client = runs.connect()
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
    schemes = parse_param(params["cv.schemes"])
    out: dict[str, Any] = {"model": name, "version": entry.version, "run": entry.run_id,
                           "features": str(path), "features md5": tags["eskin.features_md5"],
                           "estimator": type(model).__name__, "schemes": {}}
    n_jobs = int(parse_param(params.get("cv.n_jobs", "1")))
    for scheme in schemes:
        log(f"{name} v{entry.version}: {scheme} cross-validation, {params['cv.folds']} folds, "
            f"{len(frame)} rows …")
        folds = assign_folds(frame, kind, scheme, int(params["cv.folds"]), int(params["cv.seed"]),
                             skin=skin)
        redone = cross_validate(task, frame, folds, model, scheme, skin,
                                n_jobs=n_jobs).predictions
        logged = pd.read_parquet(mlflow.artifacts.download_artifacts(
            run_id=entry.run_id, artifact_path=f"predictions/oof_{scheme}.parquet"))
        column = f"{target}_pred"
        a = logged[column].to_numpy(dtype=float)
        b = redone[column].to_numpy(dtype=float)
        out["schemes"][scheme] = {"rows": len(a), "identical": int(np.sum(a == b)),
                                  "max_abs_difference": float(np.max(np.abs(a - b)))
                                  if len(a) == len(b) and len(a) else float("nan")}
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


def stack_from_registry(scene: str, alias: str, root: Path = Path(".")) -> SkinStack:
    """The stack whose task models carry the MLflow alias ``alias`` (``champion``:
    ``client.set_registered_model_alias("single_force.force", "champion", 3)``).
    Each task's file is found by the md5 its version recorded, in the workspace or
    DVC's cache, and checked before it is loaded, as ``eskin reproduce`` does; all
    must come from the same features version."""
    from eskin.tracking import runs

    client = runs.connect()
    versions = [client.get_model_version_by_alias(model.name, alias)
                for model in client.search_registered_models(f"name LIKE '{scene}.%'")
                # LIKE's "_" matches any character, and scene names have them
                if model.name.startswith(f"{scene}.") and alias in (model.aliases or {})]
    by_task = {v.tags.get("eskin.task"): v for v in versions}
    if not by_task:
        raise StackError(f"no registered model of scene {scene!r} has the alias {alias!r}: "
                         f"set one with MlflowClient().set_registered_model_alias("
                         f"'{scene}.force', '{alias}', <version>)")
    features_md5 = {v.tags.get("eskin.features_md5") for v in by_task.values()}
    if len(features_md5) != 1:
        raise StackError(f"the {alias!r} models of {scene} were trained on different "
                         f"features versions ({', '.join(sorted(map(str, features_md5)))}): "
                         "give the alias to versions of one training")
    features = versioned_file(root, features_path(scene), features_md5.pop(),
                              f"features of {scene}")
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
                     rest_reading(pd.read_parquet(processed), skin))
