"""make bench's learning curves (issue 41): a task's error against trials per condition,
beside the Bayes bound; and the planner that reads them (`eskin plan`).

Each point is measured on ``learning_curve.draws`` held-out draws: draw h holds out
repetition h of every condition (draw 0: the first trial, the dataset's own rows, which the
Bayes bound answers) and trains on the ``r`` repetitions after it, cyclically over those
recorded, for each ``r`` of ``learning_curve.repeats``. So every held-out condition was
seen ``r`` times in training, in other trials: the question the ``trials`` CV scheme asks,
at ``r`` repetitions; and the spread over draws is the spread over new recordings (another
held-out trial, another training set). The model is the pipeline's (``train.<task>``), its
features the pipeline's method fitted on the training rows.

Where the trials come from:

* a simulated scene: its plan recorded again, ``max(repeats)`` more times, on the same
  simulated skin, by acquisition's own path into a scratch copy of the scene's raw log
  (so its first repetition is the pipeline's own trials, reused, and the held-out rows
  are exactly the dataset's: the rows the bound answers);
* any other scene recorded twice or more (``repeats`` ≥ 2, or an import whose conditions
  have several trials): its own trials, in the order recorded, up to what it has.

The curve, error = floor + a · r^(−b), its floor at or above the bound's error, is fitted
by least squares (scipy's curve_fit) twice: to the draws' mean and to their lower end (the
score ``learning_curve.reliability`` of new recordings reach). The planner reads the
repetitions a target needs from the lower end's, and refuses a target beyond the fitted
floor or beyond the bound.
"""

from __future__ import annotations

import json
import math
import shutil
import tempfile
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from eskin.catalog import TASK_NAMES, processed_path, raw_dir
from eskin.config.params import Params
from eskin.data.schema import (
    contact_mask,
    dataset_kind,
    dataset_skin,
    read_dataset,
    read_metadata,
)
from eskin.evaluation.crossval import cross_validate
from eskin.evaluation.folds import conditions, trial_conditions
from eskin.evaluation.tasks import Task, get_task
from eskin.learning.choice import chosen_model
from eskin.learning.estimators import build_model
from eskin.learning.features import featurize, fit_featurizer
from eskin.tracking.planning import (
    CURVE,
    FLAT_GAIN,
    bound_caveat,
    curve_error,
    fit_curve,
    flattens_at,
    lower_end,
    plan_table,
    repeats_for,
)


def repetition(frame: pd.DataFrame, kind: str) -> np.ndarray:
    """Each row's repetition: the rank of its trial among its condition's trials, in the
    order they were recorded (0 for a condition's first trial)."""
    first = trial_conditions(frame, kind).drop_duplicates("trial")
    rank = pd.Series(first.groupby("condition").cumcount().to_numpy(),
                     index=first["trial"].to_numpy())
    return rank[frame["trial"].to_numpy()].to_numpy()


def draw_repetitions(recorded: int, r: int, draws: int) -> list[tuple[int, list[int]]]:
    """(held-out repetition, repetitions trained on) of each draw: repetition h of every
    condition held out, the ``r`` after it trained on, cyclically over the ``recorded``."""
    if r >= recorded:
        raise ValueError(f"{r} repetitions to train on need {r + 1} recorded, one held out; "
                         f"there are {recorded}")
    return [(h, [(h + k) % recorded for k in range(1, r + 1)])
            for h in range(min(draws, recorded))]


def record_repetitions(scene: str, params: Params, more: int, scratch: Path,
                       log: Callable[[str], None] = print) -> Path:
    """A simulated scene's plan recorded ``more`` times beyond its own trials, into a
    scratch copy of its raw log; the dataset of all of them (its path)."""
    from eskin.acquisition import acquire
    from eskin.steps.ingest import ingest_at

    settings = params.scenes[scene]
    grown = settings.model_copy(update={"repeats": settings.repeats + more})
    raw = scratch / "raw" / scene
    raw.mkdir(parents=True, exist_ok=True)
    for source in raw_dir(scene).iterdir():
        if source.is_file():
            shutil.copy2(source, raw / source.name)
    log(f"{scene}: recording the plan {more} more time(s) on the simulated skin …")
    report = acquire.acquire(scene, grown, raw, acquire=params.acquire, sim=params.sim,
                             board=params.sim_board, progress=False)
    log(f"  {report.summary}")
    ingest_at(scene, grown, raw, scratch / "processed", ingest=params.ingest)
    return scratch / "processed" / f"{scene}.parquet"


def point(task: Task, train: pd.DataFrame, held_out: pd.DataFrame, estimator, method: str,
          kind: str, skin) -> dict[str, Any]:
    """Fit on ``train``, score on ``held_out``: the task's scores per target, and seconds."""
    featurizer = fit_featurizer(method, train, kind, skin)
    both = pd.concat([featurize(train, featurizer, skin), featurize(held_out, featurizer, skin)],
                     ignore_index=True)
    folds = np.r_[np.full(len(train), -1), np.zeros(len(held_out), dtype=np.int64)]
    started = time.perf_counter()
    result = cross_validate(task, both, folds, estimator, "trials", skin)
    return {"scores": _means(result.summary), "headline": task.headline(result.summary),
            "seconds": round(time.perf_counter() - started, 2)}


def bound_point(task: Task, held_out: pd.DataFrame, bound_path: Path | None) -> dict | None:
    """The Bayes bound's scores on the held-out rows, where the bench has it."""
    from eskin.evaluation.folds import fold_splitter
    from harness.benchmark import bound_scores, read_bound
    from harness.oracle import CONVERGED

    if bound_path is None or not Path(bound_path).exists():
        return None
    oracle, reason = read_bound(Path(bound_path), held_out)
    if oracle is None:
        return {"unavailable": reason}
    rows = task.rows(held_out)
    scores = bound_scores(task, held_out[rows].reset_index(drop=True),
                          oracle[rows].reset_index(drop=True),
                          fold_splitter(np.zeros(int(rows.sum()), dtype=np.int64)))
    moves = oracle.attrs.get("convergence", {})
    # whether doubling the oracle's integration grid left every score in place (None:
    # not checked); eskin plan and the curves' page say so beside the bound
    converged = max(moves.values()) < CONVERGED if moves else None
    return {"headline": task.headline(scores), "scores": _means(scores),
            "convergence": moves, "converged": converged}


def _means(summary: Mapping[str, Mapping[str, float]]) -> dict[str, dict[str, float]]:
    """Each target's scores without their spreads over folds (one held-out set: none)."""
    return {target: {metric: value for metric, value in values.items()
                     if not metric.endswith("_std")}
            for target, values in summary.items()}


def _model(task: Task, params: Params, configuration: str, the_kind,
           skin) -> tuple[str, dict[str, Any]]:
    """(model name, hyperparameters) the pipeline trains for ``task`` under
    ``configuration`` (``train.configuration``, or ``paper``)."""
    task_params = getattr(params.train, task.name)
    name, hyper, _ = chosen_model(task_params, configuration, the_kind.scene_kind, skin,
                                  task.role)
    return name, hyper


def _scored_on(task: Task, frame: pd.DataFrame, result, fold_of: np.ndarray,
               rows: np.ndarray) -> float:
    """The headline score of ``result``'s out-of-fold predictions on ``rows`` of
    ``frame`` only (mean over folds of the scores on those rows), as the bound is scored."""
    from eskin.evaluation.folds import fold_splitter
    from harness.benchmark import bound_scores

    task_rows = task.rows(frame)
    keep = rows[task_rows]
    data = frame[task_rows].reset_index(drop=True)[keep].reset_index(drop=True)
    predicted = pd.DataFrame({name: result.predictions[f"{name}_pred"].to_numpy(dtype=float)
                              for name in task.targets})[keep].reset_index(drop=True)
    return task.headline(bound_scores(task, data, predicted,
                                      fold_splitter(fold_of[task_rows][keep])))


def gap_check(frame: pd.DataFrame, rep: np.ndarray, params: Params, document: dict, *,
              tasks: tuple[str, ...], share: float, folds: int, skin, the_kind,
              log: Callable[[str], None] = print) -> dict[str, Any]:
    """Issue 41's acceptance, per task: the repetitions the planner says close
    ``share`` of the gap between the paper's model (``conditions`` CV on the dataset: one
    trial per condition, the paper's protocol) and the bound; then the scene recorded that
    many times plus the held-out one, under ``trials`` CV with ``folds`` folds, the
    pipeline's model and the paper's on the same folds, scored on the first trials (the
    rows the bound answers): the share of the gap closed."""
    from eskin.evaluation.folds import assign_folds

    kind, seed = the_kind.name, int(params.cv.seed)
    held_out = frame[rep == 0].reset_index(drop=True)
    held_out_features = _featurized(held_out, params, kind, skin)
    on_dataset = assign_folds(held_out, kind, "conditions", folds, seed, skin=skin)
    # by r, once: the scene, its features, its folds, its first trials (the bound's rows)
    scenes: dict[int, tuple[pd.DataFrame, pd.DataFrame, np.ndarray, np.ndarray]] = {}
    out: dict[str, Any] = {"share": share, "folds": folds, "tasks": {}}
    for task_name in tasks:
        entry = document["tasks"].get(task_name, {})
        task = get_task(kind, task_name)
        bound = entry.get("bound", {}).get("headline")
        if entry.get("fit") is None or entry.get("low_fit") is None or bound is None:
            out["tasks"][task_name] = {"skipped": "no fitted curve or no bound"}
            continue
        paper_name, paper_hyper = _model(task, params, "paper", the_kind, skin)
        paper_error = 1.0 - task.headline(cross_validate(
            task, held_out_features, on_dataset,
            build_model(task.role, paper_name, paper_hyper, skin), "conditions", skin).summary)
        target_error = paper_error - share * (paper_error - (1.0 - bound))
        # the planner's count: the draws' lower end reaches it
        r = repeats_for(entry["low_fit"], target_error, entry["points"], key="low")
        check: dict[str, Any] = {"paper_model": paper_name, "paper_conditions": 1 - paper_error,
                                 "bound": bound, "target": 1.0 - target_error,
                                 "recommended_repeats": r,
                                 "mean_repeats": repeats_for(entry["fit"], target_error,
                                                             entry["points"])}
        log(f"{document['scene']}/{task_name}: paper's model under conditions CV "
            f"{1 - paper_error:.4f}, bound {bound:.4f}: {share:.0%} of the gap is "
            f"{task.headline_metric} {1 - target_error:.4f} → "
            + (f"{r} trial(s) per condition" if r else "not reached by the curve"))
        if r is None or r > int(rep.max()):
            check["skipped"] = "the curve does not reach it within the recorded trials"
            out["tasks"][task_name] = check
            continue
        if r not in scenes:
            scene = frame[rep <= r].reset_index(drop=True)
            scenes[r] = (scene, _featurized(scene, params, kind, skin),
                         assign_folds(scene, kind, "trials", folds, seed, skin=skin),
                         rep[rep <= r] == 0)
        scene, scene_features, fold_of, first_trials = scenes[r]
        scored = {}
        for label, (name, hyper) in (
                ("pipeline", _model(task, params, params.train.configuration, the_kind, skin)),
                ("paper", (paper_name, paper_hyper))):
            result = cross_validate(task, scene_features, fold_of,
                                    build_model(task.role, name, hyper, skin), "trials", skin)
            scored[label] = {"model": name, "all_rows": task.headline(result.summary),
                             "first_trials": _scored_on(task, scene, result, fold_of,
                                                        first_trials)}
        model_error = 1.0 - scored["pipeline"]["first_trials"]
        same_folds_paper = 1.0 - scored["paper"]["first_trials"]
        check.update({
            "scene_repeats": r + 1, "rows": len(scene), "scores": scored,
            "gap_closed": (paper_error - model_error) / (paper_error - (1.0 - bound)),
            "gap_closed_same_folds": ((same_folds_paper - model_error)
                                      / (same_folds_paper - (1.0 - bound)))})
        log(f"  {r + 1} trials per condition, trials CV ({folds} folds): "
            f"{scored['pipeline']['model']} {1 - model_error:.4f}, gap closed "
            f"{check['gap_closed']:.0%} (against the paper's model on the same folds, "
            f"{check['gap_closed_same_folds']:.0%})")
        out["tasks"][task_name] = check
    return out


def _featurized(frame: pd.DataFrame, params: Params, kind: str, skin) -> pd.DataFrame:
    """``frame`` with the pipeline's features, fitted on all of it, as the featurize step
    fits them on the whole dataset before any fold is drawn."""
    return featurize(frame, fit_featurizer(params.featurize.method, frame, kind, skin), skin)


def learning_curve(scene: str, params: Params, repeats: list[int], *,
                   bound_path: Path | None, tasks: tuple[str, ...] = TASK_NAMES,
                   gap_share: float | None = None, gap_tasks: tuple[str, ...] = (),
                   draws: int = 1, reliability: float = 0.9, scratch: Path | None = None,
                   log: Callable[[str], None] = print) -> dict[str, Any]:
    """Every task's curve for ``scene``: the document the stage writes and `eskin plan` reads."""
    settings = params.scenes[scene]
    want = max(repeats)
    with tempfile.TemporaryDirectory(prefix="eskin-curve-", dir=scratch) as work:
        path = processed_path(scene)
        simulated = settings.source == "simulated"
        if simulated:
            path = record_repetitions(scene, params, want + 1 - settings.repeats, Path(work),
                                      log)
        frame, skin, the_kind = read_dataset(path), dataset_skin(path), dataset_kind(path)
        meta = read_metadata(path)
    kind = the_kind.name
    rep = repetition(frame, kind)
    have = int(pd.Series(rep).groupby(conditions(frame, kind)).max().min())
    recorded = have + 1  # repetitions every condition has
    usable = [r for r in repeats if r <= have]
    if not usable:
        raise ValueError(f"scenes.{scene}: every condition needs two trials or more for a "
                         f"learning curve (one held out, one to train on); it has "
                         f"{have + 1}: record it with repeats ≥ 2")
    held_out = frame[rep == 0].reset_index(drop=True)
    condition = conditions(held_out, kind)
    n_conditions = int(condition.max() + 1)
    # A trial whose indenters touch the skin: the operator places weights for it.
    placed = int(len(np.unique(condition[contact_mask(held_out)])))
    document: dict[str, Any] = {
        "scene": scene, "kind": kind, "source": settings.source,
        "trials": "new trials of the simulated skin" if simulated else "the scene's own",
        "conditions": n_conditions, "placed_conditions": placed,
        "samples": int(len(held_out) // n_conditions),
        "held_out_rows": len(held_out), "repeats": usable, "curve": CURVE,
        "draws": min(draws, recorded), "reliability": reliability,
        "flat_gain": FLAT_GAIN, "dataset_rows": int(meta.get("dataset", {}).get("rows", 0))
        or len(frame), "tasks": {}}
    for task_name in tasks:
        task = get_task(kind, task_name)
        reason = task.unsupported(held_out)
        if reason is not None:
            document["tasks"][task_name] = {"skipped": reason}
            log(f"{scene}/{task_name}: skipped — {reason}")
            continue
        model_name, hyper = _model(task, params, params.train.configuration, the_kind, skin)
        points = []
        for r in usable:
            scored = []
            for held, trained in draw_repetitions(recorded, r, draws):
                scored.append(point(
                    task, frame[np.isin(rep, trained)].reset_index(drop=True),
                    frame[rep == held].reset_index(drop=True),
                    build_model(task.role, model_name, hyper, skin),
                    params.featurize.method, kind, skin))
            headlines = [s["headline"] for s in scored]
            points.append({
                "repeats": r, "train_rows": int(np.isin(rep, range(1, r + 1)).sum()),
                "headline": float(np.mean(headlines)), "draws": headlines,
                "low": lower_end(headlines, reliability),
                # draw 0's: the dataset's own rows, which the bound answers
                "first_trials": headlines[0], "scores": scored[0]["scores"],
                "seconds": round(sum(s["seconds"] for s in scored), 2)})
            log(f"{scene}/{task_name} [{model_name}]: {r} trial(s) per condition → "
                f"{task.headline_metric} {points[-1]['headline']:.4f} over {len(scored)} "
                f"draw(s) ({min(headlines):.4f}–{max(headlines):.4f}, lower end "
                f"{points[-1]['low']:.4f}; {points[-1]['seconds']} s)")
        entry: dict[str, Any] = {"model": model_name, "metric": task.headline_metric,
                                 "targets": list(task.targets), "points": points}
        bound = bound_point(task, held_out, bound_path) if simulated else None
        if bound is not None:
            entry["bound"] = bound
        # the floor never above the bound: a fitted asymptote promises no more than it allows
        least = 1.0 - bound["headline"] if bound and "headline" in bound else 0.0
        entry["fit"] = fit_curve(usable, [1.0 - p["headline"] for p in points], least)
        entry["low_fit"] = fit_curve(usable, [1.0 - p["low"] for p in points], least)
        if entry["fit"] is not None:
            entry["floor_score"] = 1.0 - entry["fit"]["floor"]
            entry["flattens_at"] = flattens_at(entry["fit"])
        if entry["low_fit"] is not None:
            entry["low_floor_score"] = 1.0 - entry["low_fit"]["floor"]
        document["tasks"][task_name] = entry
    if gap_share is not None and simulated and gap_tasks:
        document["gap_check"] = gap_check(frame, rep, params, document, tasks=gap_tasks,
                                          share=gap_share, folds=int(params.cv.folds),
                                          skin=skin, the_kind=the_kind, log=log)
    return document


def render(document: Mapping[str, Any], settings: Any) -> str:
    """The learning curves as markdown: a table per task, and each target's repetitions."""
    scene = document["scene"]
    draws = document["draws"]
    lines = [f"# Learning curves: {scene}", "",
             f"Held out, in each of {draws} draw(s): one repetition of each of "
             f"{document['conditions']:,} conditions ({document['held_out_rows']:,} rows; "
             f"draw 0 the first trials, the dataset's own); trained on the r repetitions "
             f"after it ({document['trials']}). The lower end is the score "
             f"{document['reliability']:.0%} of new recordings reach (one-sided normal "
             f"prediction bound over the draws). Fitted, to the mean and to the lower end, "
             f"the floor at or above the bound's error: {CURVE}; flat where one more "
             f"repetition gains less than {FLAT_GAIN}.", ""]
    for task_name, entry in document["tasks"].items():
        if "skipped" in entry:
            lines += [f"## {task_name}", "", f"Skipped: {entry['skipped']}", ""]
            continue
        metric = entry["metric"]
        lines += [f"## {task_name} [{entry['model']}]", "",
                  f"| trials per condition | training rows | {metric}, mean | draws | "
                  f"lower end | fitted, mean | fitted, lower end | seconds |",
                  "|---|---|---|---|---|---|---|---|"]
        for p in entry["points"]:
            fitted = [f"{1.0 - curve_error(fit, p['repeats']):.4f}" if fit else "—"
                      for fit in (entry["fit"], entry["low_fit"])]
            lines.append(f"| {p['repeats']} | {p['train_rows']:,} | {p['headline']:.4f} | "
                         f"{min(p['draws']):.4f}–{max(p['draws']):.4f} | {p['low']:.4f} | "
                         f"{fitted[0]} | {fitted[1]} | {p['seconds']:.1f} |")
        bound = entry.get("bound")
        caveat = bound_caveat(bound or {})
        if bound and "headline" in bound:
            lines.append(f"| Bayes bound (draw 0{', ' + caveat.split(':')[0] if caveat else ''}"
                         f") | — | {bound['headline']:.4f} | — | — | — | — | — |")
        lines.append("")
        if caveat:
            lines += [f"The Bayes bound has {caveat}: an estimate, not a limit.", ""]
        if entry["fit"]:
            lines += [f"Fit, {label}: floor {fit['floor']:.4f} (a {metric} of "
                      f"{1.0 - fit['floor']:.4f}), a {fit['a']:.4f}, b {fit['b']:.2f}."
                      for label, fit in (("mean", entry["fit"]),
                                         ("lower end", entry["low_fit"])) if fit]
            lines.append(f"Flat from {entry['flattens_at']} trial(s) per condition.")
        else:
            lines.append("Too few points to fit a curve.")
        if bound and "unavailable" in bound:
            lines.append(f"No Bayes bound: {bound['unavailable']}")
        lines.append("")
    lines += ["## What a target costs", "", plan_table(document, settings), ""]
    if "gap_check" in document:
        lines += render_gap_check(document, settings)
    return "\n".join(lines)


def render_gap_check(document: Mapping[str, Any], settings: Any) -> list[str]:
    """The recommended repeats under ``trials`` CV, as markdown lines; each scene's time on
    the bench at the planner's rates (sampling at ``frames_per_s``, ``placement_s`` a
    placed trial)."""
    check = document["gap_check"]
    once_s = (document["conditions"] * document["samples"] / float(settings.frames_per_s)
              + document["placed_conditions"] * float(settings.placement_s))
    lines = [f"## {check['share']:.0%} of the paper→bound gap, under trials CV", "",
             f"The paper's model under conditions CV on the dataset (one trial per condition, "
             f"the paper's protocol) and the bound set the gap; the planner gives the trials "
             f"per condition to train on that close {check['share']:.0%} of it (where the "
             f"fitted curve of the draws' lower end reaches it, past any measured point whose "
             f"lower end falls short). The "
             f"scene recorded that many times plus once (the held-out first trials) is then "
             f"scored under trials CV, {check['folds']} folds, on its first trials (the rows "
             f"the bound answers), the paper's model on the same folds beside it.", "",
             "| task | paper, conditions CV | bound | target | trials to train on | scene's "
             "trials per condition | on the bench | model, trials CV | gap closed | paper, "
             "same folds | gap closed against it |", "|---" * 11 + "|"]
    caveats = [f"The bound of {name} has {caveat}: its gap is measured to an estimate."
               for name in check["tasks"]
               if (caveat := bound_caveat(document["tasks"].get(name, {}).get("bound", {})))]
    if caveats:
        lines[4:4] = [" ".join(caveats), ""]
    for task_name, entry in check["tasks"].items():
        if "paper_conditions" not in entry:
            lines.append(f"| {task_name} | {entry.get('skipped', '')} ||||||||||")
            continue
        head = (f"| {task_name} | {entry['paper_conditions']:.4f} | {entry['bound']:.4f} | "
                f"{entry['target']:.4f} | {entry['recommended_repeats'] or '—'} | ")
        if "scores" not in entry:
            lines.append(head + f"{entry.get('skipped', '')} ||||||")
            continue
        scores = entry["scores"]
        lines.append(head + f"{entry['scene_repeats']} | "
                     f"{entry['scene_repeats'] * once_s / 3600:.1f} h | "
                     f"{scores['pipeline']['model']} "
                     f"{scores['pipeline']['first_trials']:.4f} | {entry['gap_closed']:.0%} | "
                     f"{scores['paper']['first_trials']:.4f} | "
                     f"{entry['gap_closed_same_folds']:.0%} |")
    return lines + [""]


def figure(document: Mapping[str, Any]):
    """A panel per task: error (log) against trials per condition (log), measured points,
    the fitted curve, its floor and the Bayes bound."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = {name: e for name, e in document["tasks"].items() if "points" in e}
    plot, axes = plt.subplots(1, max(len(tasks), 1), figsize=(3.4 * max(len(tasks), 1), 3.2),
                              squeeze=False, layout="constrained")
    for ax, (name, entry) in zip(axes[0], tasks.items(), strict=False):
        r = [p["repeats"] for p in entry["points"]]
        ax.vlines(r, [1 - max(p["draws"]) for p in entry["points"]],
                  [1 - min(p["draws"]) for p in entry["points"]], color="C0", lw=1,
                  label="draws' range")
        ax.plot(r, [1 - p["headline"] for p in entry["points"]], "o", color="C0",
                label="mean")
        ax.plot(r, [1 - p["low"] for p in entry["points"]], "v", color="C1",
                label="lower end")
        dense = np.geomspace(1, max(r) * 3, 100)
        for fit, color, label in ((entry["fit"], "C0", "fitted, mean"),
                                  (entry.get("low_fit"), "C1", "fitted, lower end")):
            if fit:
                ax.plot(dense, [curve_error(fit, x) for x in dense], "-", color=color, lw=1,
                        label=label)
        if entry["fit"]:
            ax.axhline(entry["fit"]["floor"], color="grey", ls=":", lw=1, label="floor")
        bound = entry.get("bound", {}).get("headline")
        if bound is not None and 1 - bound > 0:
            ax.axhline(1 - bound, color="black", ls="--", lw=1, label="Bayes bound")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("trials per condition trained on")
        ax.set_title(f"{name} [{entry['model']}]", fontsize=9)
        ax.set_ylabel(f"1 − {entry['metric']}")
    labelled = {}
    for ax in axes[0]:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            labelled.setdefault(label, handle)
    plot.legend(labelled.values(), labelled.keys(), loc="outside lower center",
                ncols=len(labelled), fontsize=8)
    plot.suptitle(f"{document['scene']}: held out, one trial of every condition, "
                  f"{document['draws']} draw(s)", fontsize=9)
    return plot


def write(document: Mapping[str, Any], text: str, out_dir: Path) -> None:
    """``<scene>.json`` (the planner reads it), ``.md`` and ``.png`` in ``out_dir``."""
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / f"{document['scene']}.json").write_text(
        json.dumps(document, indent=2, default=_finite) + "\n")
    (out_dir / f"{document['scene']}.md").write_text(
        text + f"\n\n![Learning curves]({document['scene']}.png)\n")
    plot = figure(document)
    plot.savefig(out_dir / f"{document['scene']}.png", dpi=110, metadata={"Software": None})
    plt.close(plot)


def _finite(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    raise TypeError(f"{type(value).__name__} is not JSON")
