"""Numerical stress: the cases real users' data produce, run through the real models.

Each case changes a single-force features frame the way a user's data might
(other units, float32, duplicates, a dead or saturated or doubled channel,
tiny data, another noise level) and cross-validates every model of the
default (``tuned``) and ``paper`` configurations on it, with the pipeline's
own code (:func:`eskin.evaluation.crossval.cross_validate`). Each fit runs in
a worker process, so that even a crash inside a numerical library (a
segfault) is an outcome in the table, not the end of the suite.

A case expects one of:

* ``same`` — predictions and scores equal to the unstressed run within
  :data:`TOLERANCE` (unit changes, float32, an offset);
* ``finite`` — the run completes, every prediction finite, no flood of
  warnings; the score change is reported (degenerate inputs);
* ``clear error`` — completes as ``finite`` does, or stops with an error a
  user can act on (tiny data).
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from eskin.evaluation.tasks import Task
from eskin.kinds import ONE_CONTACT
from eskin.skin import AnySkin

# Invariance tolerances of a `same` case: regression predictions within this share of
# the target's standard deviation; classifications within this share of rows; scores.
TOLERANCE = {"regression_prediction": 1e-6, "labels_changed": 0.0, "score": 1e-6}
WARNING_FLOOD = 5  # distinct warnings, or this many of any one, in a run is a flood
# The kind of scene the cases are written for (node labels, one contact's force).
KIND = ONE_CONTACT.name


def _channels(transform: Callable[[np.ndarray], np.ndarray]):
    def apply(frame: pd.DataFrame, context: Mapping[str, Any]) -> pd.DataFrame:
        channels = context["skin"].channels
        out = frame.copy()
        values = transform(frame[channels].to_numpy(dtype=np.float64))
        out[channels] = pd.DataFrame(values, index=frame.index, columns=channels)
        return out
    return apply


def _counts_to_pf(context: Mapping[str, Any]) -> Callable[[np.ndarray], np.ndarray]:
    from eskin.device.physics import SkinModel, SkinParams
    from harness.oracle import counts_to_pf

    model = SkinModel(SkinParams.from_mapping(context["sim"]))
    return lambda counts: counts_to_pf(model, counts)


def _pf(scale: float):
    def apply(frame: pd.DataFrame, context: Mapping[str, Any]) -> pd.DataFrame:
        return _channels(lambda c: _counts_to_pf(context)(c) * scale)(frame, context)
    return apply


def _float32(frame: pd.DataFrame, context: Mapping[str, Any]) -> pd.DataFrame:
    return frame.astype({c: np.float32 for c in context["skin"].channels})


def _duplicated_rows(frame: pd.DataFrame, context: Mapping[str, Any]) -> pd.DataFrame:
    return pd.concat([frame, frame], ignore_index=True)


def _repeated_samples(frame: pd.DataFrame, context: Mapping[str, Any]) -> pd.DataFrame:
    """Every sample of a trial an exact copy of its first: a board that stopped updating."""
    channels = context["skin"].channels
    out = frame.copy()
    out[channels] = frame.groupby("trial")[channels].transform("first")
    return out


def _set_channel(index: int, value: float):
    return _channels(lambda c: np.concatenate(
        [c[:, :index], np.full((len(c), 1), value), c[:, index + 1:]], axis=1))


def _collinear(frame: pd.DataFrame, context: Mapping[str, Any]) -> pd.DataFrame:
    channels = context["skin"].channels
    out = frame.copy()
    out[channels[3]] = frame[channels[2]]
    return out


def _tiny(frame: pd.DataFrame, context: Mapping[str, Any]) -> pd.DataFrame:
    """Fewer samples than classes in a fold: one sample from each of a few trials."""
    trials = frame.drop_duplicates("trial")
    return trials.sample(n=min(len(trials), 40), random_state=0).reset_index(drop=True)


def _class_absent(frame: pd.DataFrame, context: Mapping[str, Any]) -> pd.DataFrame:
    """Node column x = 10 from one trial only: absent from every other fold's training."""
    at_edge = frame["x"] == 10
    keep = frame[at_edge]["trial"].drop_duplicates().iloc[:1]
    return frame[~at_edge | frame["trial"].isin(keep)].reset_index(drop=True)


@dataclass(frozen=True)
class Case:
    name: str
    what: str
    expect: str                    # same | finite | clear error
    transform: Callable[[pd.DataFrame, Mapping[str, Any]], pd.DataFrame] | None = None
    dataset: str = "default"       # a dataset of another simulation (noise cases)


CASES: tuple[Case, ...] = (
    Case("counts", "ADC counts, as recorded (the reference)", "same", _channels(lambda c: c)),
    Case("volts", "ADC counts as volts (× 5 V / 1023)", "same",
         _channels(lambda c: c * 5.0 / 1023.0)),
    Case("picofarads", "capacitance in pF (the read-out inverted, per channel)", "same",
         _pf(1.0)),
    Case("farads", "capacitance in F (pF × 1e-12)", "same", _pf(1e-12)),
    Case("femtofarads", "capacitance in fF (pF × 1e3)", "same", _pf(1e3)),
    Case("offset", "counts plus a constant 1e6", "same", _channels(lambda c: c + 1e6)),
    Case("float32", "channels as float32", "same", _float32),
    Case("duplicated_rows", "every row twice", "finite", _duplicated_rows),
    Case("repeated_samples", "every sample of a trial identical to its first", "finite",
         _repeated_samples),
    Case("dead_channel", "channel 1 constant (512)", "finite", _set_channel(0, 512.0)),
    Case("saturated_channel", "channel 2 stuck at 1023", "finite", _set_channel(1, 1023.0)),
    Case("collinear_channels", "channel 4 a copy of channel 3", "finite", _collinear),
    Case("tiny", "40 samples, one per trial: fewer samples than classes in a fold",
         "clear error", _tiny),
    Case("class_absent", "node x = 10 in one trial only: absent from most training folds",
         "finite", _class_absent),
    Case("noise_zero", "a skin simulated without reading noise or drift", "finite",
         dataset="noise_zero"),
    Case("noise_x10", "a skin simulated with ten times the reading noise", "finite",
         dataset="noise_x10"),
)


def models_under_test(train: Any, skin: AnySkin) -> list[tuple[str, str, dict[str, Any]]]:
    """(task, model name, hyperparameters) of the tuned and paper configurations of the
    ``train`` section, as they train on ``skin``."""
    from eskin.catalog import TASK_NAMES
    from eskin.evaluation.tasks import get_task
    from eskin.learning.choice import chosen_model

    out = []
    for task in TASK_NAMES:
        task_params = getattr(train, task)
        for configuration in ("tuned", "paper"):
            name, hyper, _ = chosen_model(task_params, configuration, KIND, skin,
                                          get_task(KIND, task).role)
            if (task, name, hyper) not in out:
                out.append((task, name, hyper))
    return out


def fit_case(frame: pd.DataFrame, task_name: str, model: str, hyper: Mapping[str, Any],
             folds: int, seed: int, skin: AnySkin) -> dict[str, Any]:
    """One model's conditions cross-validation on one (stressed) frame, warnings counted.

    Runs in a worker process; returns predictions and scores, or the error."""
    from eskin.evaluation.crossval import cross_validate
    from eskin.evaluation.folds import assign_folds
    from eskin.evaluation.tasks import get_task
    from eskin.learning.estimators import build_model

    # The cases are written for one contact (stress() skips scenes of another kind).
    task = get_task(KIND, task_name)
    start = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            fold_of = assign_folds(frame, KIND, "conditions", folds, seed, skin=skin)
            result = cross_validate(task, frame, fold_of,
                                    build_model(task.role, model, hyper, skin), "conditions", skin,
                                    n_jobs=1)
        except Exception as err:  # every error is an outcome here, judged by the case
            return {"error": f"{type(err).__name__}: {err}", "warnings": _count(caught),
                    "seconds": time.perf_counter() - start}
    columns = [c for c in result.predictions if c.endswith("_pred")]
    return {"predictions": result.predictions[columns].astype(float).to_numpy(),
            "truth": {name: result.predictions[f"{name}_true"].to_numpy()
                      for name in result.per_fold},
            "scores": result.summary, "warnings": _count(caught),
            "notes": sorted(result.notes), "seconds": time.perf_counter() - start}


def _count(caught) -> dict[str, int]:
    counts: dict[str, int] = {}
    for w in caught:
        key = f"{w.category.__name__}: {str(w.message).split(chr(10))[0][:120]}"
        counts[key] = counts.get(key, 0) + 1
    return counts


def judge(case: Case, outcome: Mapping[str, Any], reference: Mapping[str, Any] | None,
          task: Task) -> dict[str, Any]:
    """The verdict on one case × model: pass, clear error, or FAIL with the reason."""
    row: dict[str, Any] = {"seconds": round(outcome["seconds"], 2),
                           "warnings": sum(outcome["warnings"].values()),
                           "warning_kinds": sorted(outcome["warnings"])}
    flood = (len(outcome["warnings"]) >= WARNING_FLOOD
             or any(n >= WARNING_FLOOD for n in outcome["warnings"].values()))
    if "error" in outcome:
        row["error"] = outcome["error"]
        clear = case.expect == "clear error" and not outcome["error"].startswith(
            ("LinAlgError", "FloatingPointError", "ZeroDivisionError", "IndexError",
             "TypeError", "AttributeError", "TerminatedWorkerError", "BrokenProcessPool"))
        row["outcome"] = "clear error" if clear else "FAIL: error"
        return row
    predictions = outcome["predictions"]
    row["score"] = task.headline(outcome["scores"])
    if not np.all(np.isfinite(predictions)):
        row["outcome"] = "FAIL: non-finite predictions"
        return row
    if flood:
        row["outcome"] = "FAIL: warning flood"
        return row
    if reference is not None and "error" not in reference:
        row["score_delta"] = row["score"] - task.headline(reference["scores"])
        if case.expect == "same":
            same, detail = _same(predictions, reference, task.scorer)
            row.update(detail)
            if not same:
                row["outcome"] = "FAIL: predictions changed"
                return row
            if abs(row["score_delta"]) > TOLERANCE["score"]:
                row["outcome"] = "FAIL: score changed"
                return row
    row["outcome"] = "pass"
    return row


def _same(predictions: np.ndarray, reference: Mapping[str, Any], scorer: str
          ) -> tuple[bool, dict[str, float]]:
    before = reference["predictions"]
    if predictions.shape != before.shape:
        return False, {"shape": f"{predictions.shape} vs {before.shape}"}
    if scorer == "regression":
        spread = np.std(np.concatenate(list(reference["truth"].values()))) or 1.0
        change = float(np.max(np.abs(predictions - before)) / spread)
        return change <= TOLERANCE["regression_prediction"], {"prediction_change": change}
    changed = float(np.mean(predictions != before))
    return changed <= TOLERANCE["labels_changed"], {"labels_changed": changed}


def run_suite(frames: Mapping[str, pd.DataFrame], params: Any, skin: AnySkin, *,
              cases: tuple[Case, ...] = CASES, folds: int = 3, seed: int = 0,
              models: list[tuple[str, str, dict[str, Any]]] | None = None,
              log=print) -> list[dict[str, Any]]:
    """Every case × model, each fit in a worker process; rows for reports/stress.json.

    ``frames``: ``default`` (the features the cases transform) and one frame per
    other dataset a case names (``noise_zero``, ``noise_x10``); ``params``: the
    :class:`eskin.config.Params` (its ``train`` and ``sim`` sections); ``skin``: the one
    the frames were taken on."""
    # A pool of our own, not loky's process-wide reusable one: joblib would later take
    # that one for its own Parallel and fail on it (it lacks joblib's temp-folder manager).
    from joblib.externals.loky import ProcessPoolExecutor

    from eskin.evaluation.tasks import get_task

    models = models or models_under_test(params.train, skin)
    context = {"sim": params.sim.model_dump(), "skin": skin}
    rows, references = [], {}
    executor = None
    try:
        for case in cases:
            if case.dataset not in frames:
                continue
            frame = frames[case.dataset]
            if case.transform is not None:
                frame = case.transform(frame, context)
            for task, model, hyper in models:
                if executor is None:
                    executor = ProcessPoolExecutor(max_workers=1, timeout=60)
                try:
                    outcome = executor.submit(fit_case, frame, task, model, hyper, folds,
                                              seed, skin).result()
                except Exception as err:  # the worker died (a segfault): an outcome, not the end
                    outcome = {"error": f"{type(err).__name__}: {err}", "warnings": {},
                               "seconds": 0.0}
                    executor.shutdown(wait=True, kill_workers=True)
                    executor = None
                key = (task, model)
                if case.name == "counts":
                    references[key] = outcome
                verdict = judge(case, outcome, references.get(key) if case.dataset == "default"
                                else None, get_task(KIND, task))
                rows.append({"case": case.name, "what": case.what, "expect": case.expect,
                             "task": task, "model": model, **verdict})
                log(f"  {case.name:<18} {task:<9} {model:<23} {verdict['outcome']}"
                    + (f" ({verdict['error'][:90]})" if "error" in verdict else ""))
    finally:
        if executor is not None:
            executor.shutdown(wait=True)
    return rows


def large_factorisation(frame: pd.DataFrame, rows: int, seed: int,
                        skin: AnySkin) -> dict[str, Any]:
    """The exact GP on ``rows`` training samples (one Cholesky of that order) in this
    process, scored on the remaining samples: the case that segfaulted OpenBLAS."""
    from sklearn.metrics import r2_score

    from eskin.evaluation.tasks import get_task
    from eskin.learning.gp import FixedKernelGaussianProcess

    task = get_task(KIND, "force")
    y = task.target_values(frame)["force"]
    X = frame[skin.channels].to_numpy(dtype=np.float64)
    order = np.random.default_rng(seed).permutation(len(frame))
    train, test = order[:rows], order[rows:]
    start = time.perf_counter()
    model = FixedKernelGaussianProcess(hyper_subsample=2000, random_state=seed)
    model.fit(X[train], y[train])
    predicted = model.predict(X[test])
    return {"case": "large_exact_gp", "what": f"exact GP, one Cholesky of order {len(train):,}",
            "expect": "finite", "task": "force", "model": "exact_gp",
            "outcome": "pass" if np.all(np.isfinite(predicted)) else "FAIL: non-finite",
            "score": float(r2_score(y[test], predicted)), "jitter": float(model.jitter_),
            "seconds": round(time.perf_counter() - start, 1), "warnings": 0}


def stress(params: Any, settings: Any, scene: str, features_path, out_dir, *, scratch,
           log=print) -> str:
    """The DVC stage: the suite on a scene's features (subsampled by trial), noise
    datasets acquired from the simulated skin (a simulated scene only), and the large
    factorisation → ``<out_dir>/<scene>.{json,md,html}``. A scene of another kind is
    written as skipped, with the reason. ``params``: the :class:`eskin.config.Params` (its
    ``sim`` and ``train`` sections and the scene's; the noise datasets are acquired,
    ingested and featurized with the pipeline's sections); ``settings``: the
    :class:`eskin.config.Stress` of stress/params.yaml."""
    import json
    from pathlib import Path

    from eskin.acquisition import acquire
    from eskin.data.schema import dataset_skin, describe_source, read_dataset, read_metadata
    from eskin.steps.featurize import featurize_at
    from eskin.steps.ingest import ingest_at

    meta = read_metadata(features_path)
    skin = dataset_skin(features_path)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    out_json, out_md, out_html = (out_dir / f"{scene}.{ext}" for ext in ("json", "md", "html"))
    if meta["kind"] != KIND:
        reason = f"the stress cases are written for {KIND} scenes; this one is {meta['kind']}"
        out_json.write_text(json.dumps({"scene": scene, "status": "skipped", "reason": reason},
                                       indent=2) + "\n")
        out_md.write_text(f"Skipped: {reason}.\n")
        out_html.write_text(f"<!doctype html><meta charset='utf-8'><title>eskin stress</title>"
                            f"<p>{scene}: skipped: {reason}.</p>\n")
        return f"stress {scene}: skipped — {reason}"
    features = read_dataset(features_path)
    trials = features["trial"].drop_duplicates().sample(
        n=min(int(settings.trials), features["trial"].nunique()),
        random_state=int(settings.seed))
    frames = {"default": features[features["trial"].isin(trials)].reset_index(drop=True)}
    simulated = meta.get("source", {}).get("kind") == "simulated"
    noise_note = ("run" if simulated else "skipped: they simulate the skin again, and this "
                  f"data is {describe_source(meta)}")
    if not simulated:
        log(f"stress {scene}: noise cases {noise_note}")
    for name, factor in (("noise_zero", 0.0), ("noise_x10", 10.0)) if simulated else ():
        sim = params.sim.model_copy(update={
            knob: getattr(params.sim, knob) * factor
            for knob in ("noise_pf", "drift_offset_pf")})
        noisy = params.scenes[scene].model_copy(update=settings.noise_scene.model_dump())
        root = Path(scratch) / name
        acquire.acquire(scene, noisy, root / "raw", acquire=params.acquire, sim=sim,
                        board=params.sim_board, progress=False)
        ingest_at(scene, noisy, root / "raw", root / "processed", ingest=params.ingest)
        featurize_at(scene, root / "processed", root / "features", root / "models",
                     settings=params.featurize)
        frames[name] = read_dataset(root / "features" / f"{scene}.parquet")
    log(f"stress: {len(frames['default']):,} samples of {len(trials)} trials, "
        f"{int(settings.folds)}-fold conditions CV")
    rows = run_suite(frames, params, skin, folds=int(settings.folds), seed=int(settings.seed),
                     log=log)
    if int(settings.large_gp_rows) > 0:
        log(f"  large_exact_gp: exact GP on {int(settings.large_gp_rows):,} samples …")
        rows.append(large_factorisation(features, int(settings.large_gp_rows),
                                        int(settings.seed), skin))
        log(f"  large_exact_gp     force     exact_gp                {rows[-1]['outcome']} "
            f"({rows[-1]['seconds']} s, R² {rows[-1]['score']:.3f})")
    doc = {"scene": scene, "source": describe_source(meta), "noise_cases": noise_note,
           "tolerance": TOLERANCE,
           "warning_flood": WARNING_FLOOD, "rows": rows,
           "samples": len(frames["default"]), "folds": int(settings.folds),
           "failed": sum(r["outcome"].startswith("FAIL") for r in rows)}
    out_json.write_text(json.dumps(doc, indent=2, sort_keys=True) + "\n")
    out_md.write_text(stress_markdown(rows))
    out_html.write_text(stress_html(rows, doc))
    return (f"stress {scene}: {len(rows)} case × model runs, {doc['failed']} failed "
            f"→ {out_json}, {out_md}, {out_html}")


def stress_html(rows: list[Mapping[str, Any]], doc: Mapping[str, Any]) -> str:
    """A page beside the report: the per-case table, then every case × model run."""
    columns = ["case", "task", "model", "expect", "outcome", "score", "score_delta",
               "prediction_change", "labels_changed", "warnings", "seconds", "error"]
    table = pd.DataFrame(rows).reindex(columns=columns)
    summary = stress_markdown(rows).splitlines()
    head = [cell.strip() for cell in summary[0].strip("|").split("|")]
    body = [[cell.strip() for cell in line.strip("|").split("|")] for line in summary[2:]]
    return ("<!doctype html><html><head><meta charset='utf-8'><title>eskin stress</title>"
            "<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}"
            "td,th{border:1px solid #ccc;padding:2px 6px;font-size:90%}</style></head><body>"
            f"<h1>Numerical stress: {doc['scene']}</h1><p>{doc['samples']:,} samples of "
            f"{doc['source']}, {doc['folds']}-fold "
            f"conditions CV per case and model; tolerances {doc['tolerance']}; "
            f"{doc['failed']} failed.</p>"
            + pd.DataFrame(body, columns=head).to_html(index=False, escape=True)
            + "<h2>Every run</h2>"
            + table.to_html(index=False, na_rep="", float_format=lambda v: f"{v:.3g}")
            + "</body></html>\n")


def stress_markdown(rows: list[Mapping[str, Any]]) -> str:
    """One line per case: its outcome over the models, the largest score change."""
    table = pd.DataFrame(rows)
    lines = ["| case | what | expected | outcome | models | largest score change | seconds |",
             "|---|---|---|---|---|---|---|"]
    for case, group in table.groupby("case", sort=False):
        outcomes = group["outcome"].value_counts()
        outcome = ", ".join(f"{k} ×{v}" if len(outcomes) > 1 else k for k, v in outcomes.items())
        delta = group["score_delta"].abs().max() if "score_delta" in group else np.nan
        errors = "; ".join(sorted({f"{r.model}: {r.error}" for r in group.itertuples()
                                   if isinstance(getattr(r, "error", None), str)}))
        lines.append(f"| {case} | {group['what'].iloc[0]} | {group['expect'].iloc[0]} | "
                     f"{outcome}{' — ' + errors[:200] if errors else ''} | {len(group)} | "
                     f"{'—' if pd.isna(delta) else f'{delta:.2g}'} | "
                     f"{group['seconds'].sum():.1f} |")
    return "\n".join(lines) + "\n"
