"""Pipeline steps shared by the DVC stages and the ``eskin`` command line.

Each reads its params sections, calls the library, and writes its outputs:
the same code runs under ``dvc repro`` and by hand.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import joblib
import pandas as pd

from eskin.acquisition.session import LOG_NAME, acquire_scene
from eskin.config import scene_plan, section, skin_params
from eskin.data.importer import copy_import, find_import, import_paper_layout
from eskin.data.ingest import ingest_log
from eskin.data.schema import md5_file, read_dataset, read_metadata, write_dataset, write_quarantine
from eskin.evaluation.crossval import cross_validate, fit_final
from eskin.evaluation.cv import assign_folds
from eskin.features import featurize as featurize_frame
from eskin.features import fit_featurizer
from eskin.models import build_model, model_settings
from eskin.tasks import get_task


def acquire(params: dict[str, Any], scene: str, raw_dir: Path, *, progress: bool = True) -> str:
    """Acquire (or import) ``scene`` into ``raw_dir``; returns a one-paragraph summary."""
    plan = scene_plan(params, scene)
    settings = section(params, "acquire")
    if settings["source"] == "import":
        source = section(params, f"scenes.{scene}").get("import_path")
        if not source:
            raise ValueError(f"acquire.source is 'import' but scenes.{scene}.import_path is unset")
        target = copy_import(Path(source), raw_dir, plan.kind)
        return f"{scene}: imported {source} as {target}"
    board = section(params, "sim_board")
    report = acquire_scene(
        plan, raw_dir, source=settings["source"], sim=skin_params(params),
        rest_length_mm=float(settings["rest_length_mm"]), port=settings.get("port"),
        corrupt_fraction=float(board["corrupt_fraction"]),
        frame_period_ms=int(board["frame_period_ms"]), timeout_s=float(settings["timeout_s"]),
        max_attempts=int(settings["max_attempts"]), progress=progress)
    return report.summary()


def ingest(params: dict[str, Any], scene: str, raw_dir: Path, processed_dir: Path) -> str:
    """Raw data of ``scene`` → ``<processed_dir>/<scene>.parquet`` and its quarantine CSV."""
    plan = scene_plan(params, scene)
    bad_rows = section(params, "ingest.bad_rows")
    if section(params, "acquire.source") == "import":
        result = import_paper_layout(find_import(raw_dir), plan.kind, bad_rows=bad_rows,
                                     scene=scene)
    else:
        result = ingest_log(Path(raw_dir) / LOG_NAME, plan, bad_rows=bad_rows)
    out = Path(processed_dir) / f"{scene}.parquet"
    write_dataset(result.frame, plan.kind, out, result.metadata)
    write_quarantine(result.quarantine, Path(processed_dir) / f"{scene}.quarantine.csv")
    note = f"; {len(result.quarantine)} row(s) quarantined" if result.quarantine else ""
    return f"{scene}: {len(result.frame)} rows → {out}{note}"


def featurize(params: dict[str, Any], scene: str, processed_dir: Path, features_dir: Path,
              models_dir: Path) -> str:
    """``<processed>/<scene>.parquet`` → ``<features>/<scene>.parquet`` + the fitted transform."""
    source = Path(processed_dir) / f"{scene}.parquet"
    if not source.exists():
        raise FileNotFoundError(f"{source}: no dataset; run `dvc repro ingest@{scene}` first")
    meta = read_metadata(source)
    frame = read_dataset(source)
    method = section(params, "featurize.method")
    featurizer = fit_featurizer(method, frame, meta["kind"])
    out = Path(features_dir) / f"{scene}.parquet"
    meta.update(featurize={"method": method},
                dataset={"path": source.as_posix(), "md5": md5_file(source), "rows": len(frame)})
    write_dataset(featurize_frame(frame, featurizer), meta["kind"], out, meta)
    transform = Path(models_dir) / scene / "featurizer.joblib"
    transform.parent.mkdir(parents=True, exist_ok=True)
    joblib.dump(featurizer, transform)
    return f"{scene}: {len(frame)} rows featurized ({method}) → {out}"


def train(params: dict[str, Any], scene: str, task_name: str, features_dir: Path, *,
          metrics_path: Path, predictions_path: Path, model_path: Path,
          params_text: str = "", track: bool = True) -> str:
    """Cross-validate one task under each CV scheme, refit, save, and log to MLflow."""
    source = Path(features_dir) / f"{scene}.parquet"
    if not source.exists():
        raise FileNotFoundError(f"{source}: no features; run `dvc repro featurize@{scene}` first")
    meta = read_metadata(source)
    frame = read_dataset(source)
    kind = meta["kind"]
    task = get_task(kind, task_name)
    task_params = section(params, f"train.{scene}.{task_name}")
    model_name, hyper = model_settings(task_params)
    estimator = build_model(task.role, model_name, hyper)
    cv = section(params, "cv")
    header = {"scene": scene, "task": task_name, "model": model_name,
              "dataset_md5": meta["dataset"]["md5"]}

    reason = task.unsupported(frame)
    if reason is not None:
        write_json({**header, "status": "skipped", "reason": reason}, metrics_path)
        save_predictions(pd.DataFrame(), predictions_path)
        save_models({"skipped": reason}, model_path)
        return f"{scene}/{task_name}: skipped — {reason}"

    results = []
    for scheme in cv["schemes"]:
        folds = assign_folds(frame, kind, scheme, int(cv["folds"]), int(cv["seed"]))
        results.append(cross_validate(task, frame, folds, estimator, scheme,
                                      n_jobs=int(cv.get("n_jobs", 1))))
    models = fit_final(task, frame, estimator)
    metrics_doc = {**header, "status": "trained", "rows": int(task.rows(frame).sum()),
                   **{r.scheme: r.summary for r in results}}
    confusion = {r.scheme: r.confusion for r in results if r.confusion}
    if confusion:
        metrics_doc["confusion"] = confusion  # lists: `dvc metrics show` passes over them
    write_json(metrics_doc, metrics_path)
    save_predictions(pd.concat([r.predictions.assign(scheme=r.scheme) for r in results],
                               ignore_index=True), predictions_path)
    save_models(models, model_path)
    run_note = ""
    if track:
        from eskin import tracking  # MLflow takes seconds to import; only training needs it

        run_id = tracking.log_task_run(
            scene=scene, task=task_name, params={"model": model_name, model_name: hyper, "cv": cv},
            params_text=params_text, results=results, models=models,
            dataset=frame.drop(columns=["session", "trial", "seq", "t_ms"]),
            dataset_digest=meta["dataset"]["md5"], dataset_source=meta["dataset"]["path"])
        run_note = f"; MLflow run {run_id}"
    headline = ", ".join(f"{r.scheme} {_headline(r.summary)}" for r in results)
    notes = "".join(f"\n  note ({r.scheme}, {n} of {len(r.per_fold[next(iter(r.per_fold))])} "
                    f"folds): {text}" for r in results for text, n in sorted(r.notes.items()))
    return f"{scene}/{task_name} [{model_name}]: {headline}{run_note}{notes}"


def _headline(summary: dict[str, dict[str, float]]) -> str:
    parts = []
    for target, scores in summary.items():
        name = "r2" if "r2" in scores else "accuracy"
        parts.append(f"{target} {name} {scores[name]:.3f}±{scores[name + '_std']:.3f}")
    return " ".join(parts)


def write_json(document: dict, path: Path) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(document, indent=2, sort_keys=True, allow_nan=True) + "\n")


def save_predictions(frame: pd.DataFrame, path: Path) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    frame.to_parquet(path, index=False)


def save_models(models: dict, path: Path) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    joblib.dump(models, path)
