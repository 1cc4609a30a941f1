"""What a target costs: the repetitions a learning curve says it needs, and the bench time
they take (`eskin plan`; the curves are make bench's, harness/learning_curve.py).

A curve is a task's error (1 − its headline score) against trials per condition ``r``,
fitted as error = floor + a · r^(−b) (:func:`fit_curve`), its floor never below the Bayes
bound's error: a fitted asymptote promises no more than the bound allows. Each point is
measured on several held-out draws (a held-out repetition of every condition, the model
trained on ``r`` others); two curves are fitted, one to the draws' mean and one to their
lower end (:func:`lower_end`: the score that ``reliability`` of new recordings reach).

A target is refused where it lies beyond the Bayes bound (no model of these readings
reaches it) or beyond the fitted floor (this model, however much data). Otherwise the plan
is the fewest repetitions whose *lower-end* curve reaches it, past every measured point
whose lower end misses it: what a lab that records that many can count on. A target the
mean reaches but the lower end does not is "reachable on average, not reliably"; a count
beyond the measured points is read from the curve and said to be no promise.

The plan's ``r`` is trials per condition to train on. Scoring it under the ``trials`` CV
scheme needs one more: each fold holds one trial of every condition out and trains on the
others, so a scene of ``repeats: r + 1`` is scored as a model trained on ``r``.
"""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

# One more repetition that gains less than this in the headline score: the curve is flat.
FLAT_GAIN = 0.001
# The most repetitions a plan is read for: past this a target is out of reach in practice.
MOST_REPEATS = 1000
CURVE = "error = floor + a · r^(−b)"


def read_curves(path: Path, scene: str) -> dict[str, Any]:
    """make bench's learning curves of ``scene`` (``reports/learning_curve/<scene>.json``)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no learning curves for scene {scene}; run "
                                f"`cd bench && dvc repro learning_curve@{scene}` (make bench)")
    document = json.loads(path.read_text())
    if any("points" in entry and "low_fit" not in entry
           for entry in document.get("tasks", {}).values()):
        raise ValueError(f"{path}: curves of one held-out draw, written before the planner "
                         f"read the spread over draws; run `cd bench && dvc repro "
                         f"learning_curve@{scene}` (make bench)")
    return document


def lower_end(scores: Sequence[float], reliability: float) -> float:
    """The score at least ``reliability`` of new recordings reach, from ``scores`` on
    held-out draws: the one-sided normal prediction bound, mean − t · sd · √(1 + 1/n)
    (Student's t at ``reliability`` with n − 1 degrees of freedom: few draws widen it).
    One draw has no spread: its score."""
    from scipy.stats import t

    values = np.asarray(scores, float)
    if len(values) < 2:
        return float(values[0])
    n = len(values)
    return float(values.mean() - t.ppf(reliability, n - 1) * values.std(ddof=1)
                 * math.sqrt(1 + 1 / n))


def fit_curve(repeats: list[int], errors: list[float],
              least_floor: float = 0.0) -> dict[str, float] | None:
    """floor, a, b of error = floor + a · r^(−b), least squares, the floor at least
    ``least_floor`` (the Bayes bound's error); None with fewer than three points or no fit."""
    from scipy.optimize import OptimizeWarning, curve_fit

    if len(repeats) < 3:
        return None
    r, e = np.asarray(repeats, float), np.asarray(errors, float)
    least_floor = min(max(float(least_floor), 0.0), 1.0 - 1e-9)
    start_floor = min(max(e.min() * 0.9, least_floor), 1.0 - 1e-9)
    try:
        with warnings.catch_warnings():
            # as many points as parameters fit exactly: no covariance (none is used)
            warnings.simplefilter("ignore", OptimizeWarning)
            (floor, a, b), _ = curve_fit(
                lambda r, floor, a, b: floor + a * r ** -b, r, e,
                p0=(start_floor, max(e[0] - start_floor, 1e-6), 1.0),
                bounds=([least_floor, 0.0, 0.05], [1.0, 10.0, 4.0]), maxfev=20000)
    except (RuntimeError, ValueError):
        return None
    return {"floor": float(floor), "a": float(a), "b": float(b)}


def curve_error(fit: Mapping[str, float], r: float) -> float:
    return fit["floor"] + fit["a"] * r ** -fit["b"]


def flattens_at(fit: Mapping[str, float], limit: int = 1000) -> int | None:
    """The first r at which one more repetition gains less than :data:`FLAT_GAIN`."""
    for r in range(1, limit + 1):
        if curve_error(fit, r) - curve_error(fit, r + 1) < FLAT_GAIN:
            return r
    return None


def repeats_for(fit: Mapping[str, float], error: float,
                points: Sequence[Mapping[str, Any]] = (), key: str = "headline",
                limit: int = MOST_REPEATS) -> int | None:
    """The fewest repetitions whose fitted error is at most ``error``, and more than any
    measured point (``points``: the curve's, ``repeats`` and the score ``key``) whose own
    error misses it (None: beyond the floor, or beyond ``limit``).

    A fit smooths the points; where one was measured and missed, the plan does not take the
    fit's word over it (two-contact force: fitted 0.818 at 2 trials, measured 0.8166).
    """
    if error <= fit["floor"]:
        return None
    missed = [int(p["repeats"]) for p in points if 1.0 - float(p[key]) > error]
    for r in range(max(missed, default=0) + 1, limit + 1):
        if curve_error(fit, r) <= error:
            return r
    return None


def target_key(task: str, metric: str) -> str:
    """A planner target's name: ``force_r2``, ``localise_accuracy``."""
    return f"{task}_{metric}"


def plan(document: Mapping[str, Any], target: str, value: float, settings: Any) -> dict:
    """How many repetitions ``target`` (``<task>_<metric>``) = ``value`` needs for
    ``reliability`` of new recordings to reach it, and what they cost on the bench; or why
    no number of them does.

    Verdicts: ``reliable`` (the lower end reaches it within the measured points: a promise),
    ``extrapolated`` (the lower end's curve reaches it past them: no promise), ``not
    reliably`` (the mean's curve reaches it, the lower end's never does), ``beyond the
    floor``, ``out of reach``, ``impossible`` (beyond the bound), ``beyond an unconverged
    bound`` (beyond a bound whose integration has not converged: no limit), ``unknown``.
    An answer that quotes the bound says where it has not converged
    (:func:`bound_caveat`)."""
    tasks = document["tasks"]
    known = {target_key(name, entry["metric"]): name for name, entry in tasks.items()
             if "metric" in entry}
    if target not in known:
        raise ValueError(f"unknown target {target!r} for scene {document['scene']}; one of: "
                         f"{', '.join(sorted(known))}")
    entry = tasks[known[target]]
    draws = int(document.get("draws", 1))
    reliability = float(document.get("reliability", settings.reliability))
    answer: dict[str, Any] = {"scene": document["scene"], "target": target, "value": value,
                              "model": entry["model"], "draws": draws,
                              "reliability": reliability}
    bound = entry.get("bound", {}).get("headline")
    caveat = bound_caveat(entry.get("bound", {}))
    if bound is not None and value > bound and entry["bound"].get("converged") is False:
        return {**answer, "verdict": "beyond an unconverged bound",
                "why": f"beyond the Bayes bound's {bound:.4f}, which has {caveat}: an "
                       "estimate, not a limit; no count of trials is read past it"}
    if bound is not None and value > bound:
        return {**answer, "verdict": "impossible",
                "why": f"impossible, the bound is {bound:.4f}: no model of these readings "
                       f"scores more" + (f" ({caveat})" if caveat else "")}
    fit, low_fit = entry.get("fit"), entry.get("low_fit")
    if fit is None or low_fit is None:
        return {**answer, "verdict": "unknown", "why": "the curve has too few points to fit"}
    error = 1.0 - value
    mean_r = repeats_for(fit, error, entry["points"])
    low_r = repeats_for(low_fit, error, entry["points"], key="low")
    answer["mean_repeats"] = mean_r
    spread = (f"the lower end of the spread over {draws} held-out draws "
              f"({reliability:.0%} of new recordings)")
    if low_r is None and mean_r is not None:
        return {**answer, "verdict": "not reliably",
                "why": f"reachable on average ({mean_r} trial(s) per condition) but not "
                       f"reliably: {spread} "
                       + (f"needs more than {MOST_REPEATS} by its fitted curve"
                          if error > low_fit["floor"] else
                          f"levels off at {1.0 - low_fit['floor']:.4f}")}
    if low_r is None and error > fit["floor"]:
        return {**answer, "verdict": "out of reach",
                "why": f"out of reach: more than {MOST_REPEATS} trials per condition by the "
                       f"fitted curve, which levels off at {entry['floor_score']:.4f}"}
    if low_r is None:
        return {**answer, "verdict": "beyond the floor",
                "why": f"beyond the floor: {entry['model']} levels off at "
                       f"{entry['floor_score']:.4f}" + (f" (the bound is {bound:.4f}"
                                                       + (f", {caveat}" if caveat else "")
                                                       + ": a better model, not more data)"
                                                       if bound is not None else "")}
    r = low_r
    trials = r * document["conditions"]
    frames = trials * document["samples"]
    sampling_s = frames / float(settings.frames_per_s)
    placements = r * document["placed_conditions"]
    placing_s = placements * float(settings.placement_s)
    measured = max((p["repeats"] for p in entry["points"]), default=0)
    extrapolated = r > measured
    on_average = (f"; on average {mean_r}" if mean_r is not None and mean_r != r else "")
    why = (f"{r} trial(s) per condition to train on: {spread} reaches it{on_average}"
           if not extrapolated else
           f"at least {r} trial(s) per condition to train on, read beyond the {measured} "
           f"measured from the fitted curve of {spread}: no promise, measure further "
           f"(learning_curve.repeats){on_average}")
    return {**answer, "verdict": "extrapolated" if extrapolated else "reliable",
            "repeats": r, "trials": trials, "placements": placements, "frames": frames,
            "sampling_s": sampling_s, "placing_s": placing_s,
            "bench_h": (sampling_s + placing_s) / 3600, "extrapolated": extrapolated,
            "why": why}


def bound_caveat(bound: Mapping[str, Any]) -> str:
    """'' for a Bayes bound whose integration converged (harness/learning_curve.py's
    ``converged``); else ``NOT converged`` and what doubling its grid moved, or
    ``convergence not checked`` (a curve written before the check was kept with it)."""
    if "headline" not in bound or bound.get("converged") is True:
        return ""
    moves = bound.get("convergence") or {}
    if bound.get("converged") is False and moves:
        worst = max(moves, key=moves.get)
        return f"NOT converged: doubling its integration moves {worst} by {moves[worst]:.4f}"
    return "convergence not checked"


# The verdicts that come with a count of repetitions and its cost.
COUNTED = ("reliable", "extrapolated")


def describe(answer: Mapping[str, Any], settings: Any) -> str:
    """The planner's answer as one paragraph: the count to train on, how the ``trials``
    CV scheme counts it, and its cost."""
    head = f"{answer['scene']}: {answer['target']} ≥ {answer['value']:g} [{answer['model']}]: "
    if answer["verdict"] not in COUNTED:
        return head + answer["why"] + "."
    r = answer["repeats"]
    return (head + f"repeats: {r} — {answer['why']}. Record `repeats: {r}` and train on "
            f"all of it; to score it under `trials` CV record `repeats: {r + 1}` (each fold "
            f"holds one trial of every condition out and trains on the other {r}). "
            f"{answer['trials']:,} trials, {answer['frames']:,} frames: "
            f"{_duration(answer['sampling_s'])} of sampling at "
            f"{float(settings.frames_per_s):g} frames/s, {_duration(answer['placing_s'])} "
            f"placing weights ({answer['placements']:,} placements at "
            f"{float(settings.placement_s):g} s); about {answer['bench_h']:.1f} h on the "
            f"bench.")


def plan_table(document: Mapping[str, Any], settings: Any) -> str:
    """Each task at three targets, a quarter, half and three quarters of the way from its
    score at one trial per condition to the bound (or to 1 without one): the repetitions
    the mean and the lower end need, and bench hours, or why none do."""
    rows = ["| task | target | on average | reliably | bench time | |",
            "|---|---|---|---|---|---|"]
    for name, entry in document["tasks"].items():
        if "metric" not in entry:
            continue
        key = target_key(name, entry["metric"])
        first = entry["points"][0]["headline"]
        bound = entry.get("bound", {}).get("headline")
        ceiling = bound if bound is not None else 1.0
        caveat = bound_caveat(entry.get("bound", {}))
        to = f" to a bound {caveat}" if caveat else ""
        if ceiling - first < FLAT_GAIN:
            rows.append(f"| {name} | — | 1 | — | — | within {FLAT_GAIN} of "
                        f"{'the bound' if bound is not None else '1'} at one trial"
                        f"{f' ({caveat})' if caveat else ''} |")
            continue
        for share in (0.25, 0.5, 0.75):
            value = first + share * (ceiling - first)
            answer = plan(document, key, value, settings)
            target = f"{key} ≥ {value:.4f} ({share:.0%} of the way{to})"
            mean = answer.get("mean_repeats") or "—"
            if answer["verdict"] in COUNTED:
                rows.append(f"| {name} | {target} | {mean} | {answer['repeats']} | "
                            f"{answer['bench_h']:.1f} h | "
                            f"{'extrapolated: no promise' if answer['extrapolated'] else ''} |")
            else:
                rows.append(f"| {name} | {target} | {mean} | — | — | {answer['verdict']} |")
    return "\n".join(rows)


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"
