"""What a target costs: the repetitions a learning curve says it needs, and the bench time
they take (`eskin plan`; the curves are make bench's, harness/learning_curve.py).

A curve is a task's error (1 − its headline score) against trials per condition ``r``,
fitted as error = floor + a · r^(−b) (:func:`fit_curve`). A target is refused where it lies
beyond the Bayes bound (no model of these readings reaches it) or beyond the fitted floor
(this model, however much data); otherwise the fewest repetitions whose fitted error
reaches it, past every measured point that misses it, their frames at the board's frame
rate, and the operator's placements at a stated time each.
"""

from __future__ import annotations

import json
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
    return json.loads(path.read_text())


def fit_curve(repeats: list[int], errors: list[float]) -> dict[str, float] | None:
    """floor, a, b of error = floor + a · r^(−b), least squares; None with fewer than three
    points or no fit."""
    from scipy.optimize import OptimizeWarning, curve_fit

    if len(repeats) < 3:
        return None
    r, e = np.asarray(repeats, float), np.asarray(errors, float)
    try:
        with warnings.catch_warnings():
            # as many points as parameters fit exactly: no covariance (none is used)
            warnings.simplefilter("ignore", OptimizeWarning)
            (floor, a, b), _ = curve_fit(
                lambda r, floor, a, b: floor + a * r ** -b, r, e,
                p0=(max(e.min() * 0.9, 0.0), max(e[0] - e.min(), 1e-6), 1.0),
                bounds=([0.0, 0.0, 0.05], [1.0, 10.0, 4.0]), maxfev=20000)
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
                points: Sequence[Mapping[str, Any]] = (),
                limit: int = MOST_REPEATS) -> int | None:
    """The fewest repetitions whose fitted error is at most ``error``, and more than any
    measured point (``points``: the curve's, ``repeats`` and ``headline``) whose own error
    misses it (None: beyond the floor, or beyond ``limit``).

    A fit smooths the points; where one was measured and missed, the plan does not take the
    fit's word over it (two-contact force: fitted 0.818 at 2 trials, measured 0.8166).
    """
    if error <= fit["floor"]:
        return None
    missed = [int(p["repeats"]) for p in points if 1.0 - float(p["headline"]) > error]
    for r in range(max(missed, default=0) + 1, limit + 1):
        if curve_error(fit, r) <= error:
            return r
    return None


def target_key(task: str, metric: str) -> str:
    """A planner target's name: ``force_r2``, ``localise_accuracy``."""
    return f"{task}_{metric}"


def plan(document: Mapping[str, Any], target: str, value: float, settings: Any) -> dict:
    """How many repetitions ``target`` (``<task>_<metric>``) = ``value`` needs, and what
    they cost on the bench; or why no number of them reaches it."""
    tasks = document["tasks"]
    known = {target_key(name, entry["metric"]): name for name, entry in tasks.items()
             if "metric" in entry}
    if target not in known:
        raise ValueError(f"unknown target {target!r} for scene {document['scene']}; one of: "
                         f"{', '.join(sorted(known))}")
    entry = tasks[known[target]]
    answer: dict[str, Any] = {"scene": document["scene"], "target": target, "value": value,
                              "model": entry["model"]}
    bound = entry.get("bound", {}).get("headline")
    if bound is not None and value > bound:
        return {**answer, "verdict": "impossible",
                "why": f"impossible, the bound is {bound:.4f}: no model of these readings "
                       f"scores more"}
    fit = entry.get("fit")
    if fit is None:
        return {**answer, "verdict": "unknown", "why": "the curve has too few points to fit"}
    r = repeats_for(fit, 1.0 - value, entry["points"])
    if r is None and 1.0 - value > fit["floor"]:
        return {**answer, "verdict": "out of reach",
                "why": f"out of reach: more than {MOST_REPEATS} trials per condition by the "
                       f"fitted curve, which levels off at {entry['floor_score']:.4f}"}
    if r is None:
        return {**answer, "verdict": "beyond the floor",
                "why": f"beyond the floor: {entry['model']} levels off at "
                       f"{entry['floor_score']:.4f}" + (f" (the bound is {bound:.4f}: a "
                                                       "better model, not more data)"
                                                       if bound is not None else "")}
    trials = r * document["conditions"]
    frames = trials * document["samples"]
    sampling_s = frames / float(settings.frames_per_s)
    placements = r * document["placed_conditions"]
    placing_s = placements * float(settings.placement_s)
    measured = max((p["repeats"] for p in entry["points"]), default=0)
    return {**answer, "verdict": "possible", "repeats": r, "trials": trials,
            "placements": placements, "frames": frames, "sampling_s": sampling_s,
            "placing_s": placing_s, "bench_h": (sampling_s + placing_s) / 3600,
            "extrapolated": r > measured,
            "why": f"{r} trial(s) per condition"
                   + (f" (beyond the {measured} measured: read from the fitted curve)"
                      if r > measured else "")}


def describe(answer: Mapping[str, Any], settings: Any) -> str:
    """The planner's answer as one paragraph."""
    head = f"{answer['scene']}: {answer['target']} ≥ {answer['value']:g} [{answer['model']}]: "
    if answer["verdict"] != "possible":
        return head + answer["why"] + "."
    return (head + f"repeats: {answer['repeats']} — {answer['why']}; {answer['trials']:,} "
            f"trials, {answer['frames']:,} frames: {_duration(answer['sampling_s'])} of "
            f"sampling at {float(settings.frames_per_s):g} frames/s, "
            f"{_duration(answer['placing_s'])} placing weights ({answer['placements']:,} "
            f"placements at {float(settings.placement_s):g} s); about "
            f"{answer['bench_h']:.1f} h on the bench.")


def plan_table(document: Mapping[str, Any], settings: Any) -> str:
    """Each task at three targets, a quarter, half and three quarters of the way from its
    score at one trial per condition to the bound (or to 1 without one): the repetitions
    and bench hours each needs, or why none do."""
    rows = ["| task | target | repetitions | bench time | |", "|---|---|---|---|---|"]
    for name, entry in document["tasks"].items():
        if "metric" not in entry:
            continue
        key = target_key(name, entry["metric"])
        first = entry["points"][0]["headline"]
        bound = entry.get("bound", {}).get("headline")
        ceiling = bound if bound is not None else 1.0
        if ceiling - first < FLAT_GAIN:
            rows.append(f"| {name} | — | 1 | — | within {FLAT_GAIN} of "
                        f"{'the bound' if bound is not None else '1'} at one trial |")
            continue
        for share in (0.25, 0.5, 0.75):
            value = first + share * (ceiling - first)
            answer = plan(document, key, value, settings)
            target = f"{key} ≥ {value:.4f} ({share:.0%} of the way)"
            if answer["verdict"] == "possible":
                rows.append(f"| {name} | {target} | {answer['repeats']} | "
                            f"{answer['bench_h']:.1f} h | "
                            f"{'extrapolated' if answer['extrapolated'] else ''} |")
            else:
                rows.append(f"| {name} | {target} | — | — | {answer['verdict']} |")
    return "\n".join(rows)


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"
