"""Registered models and their lineage: load one, and reproduce its run on its dataset.

Every training run registers its final models (``eskin.tracking.registered_name``)
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

from eskin.catalog import features_path, model_path
from eskin.data.schema import md5_file, read_dataset, read_metadata
from eskin.evaluation.crossval import cross_validate
from eskin.evaluation.cv import assign_folds
from eskin.experiments import NoRunsError, dvc_cache_path, parse_param
from eskin.learn import load_models
from eskin.tasks import get_task


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

    from eskin import tracking

    client = tracking.connect()
    entry = model_version(client, name, version)
    tags = entry.tags
    scene, task_name, target = tags["eskin.scene"], tags["eskin.task"], tags["eskin.target"]
    run = client.get_run(entry.run_id)
    path = versioned_file(root, features_path(scene),
                          tags["eskin.features_md5"], f"features of {scene}")
    frame, kind = read_dataset(path), read_metadata(path)["kind"]
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
        folds = assign_folds(frame, kind, scheme, int(params["cv.folds"]), int(params["cv.seed"]))
        redone = cross_validate(task, frame, folds, model, scheme, n_jobs=n_jobs).predictions
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
