"""make bench's live hour (issue 39): the live stack on the simulated board for an hour
of board time, streamed faster than real time, scored against the script's ground truth.

The script (:func:`script`, seeded) is untouched minutes; single presses at random nodes
and forces (the scene's force levels); one sustained press; stretch changes. The board is
the one `eskin live --simulated` starts (params.yaml's sim and sim_board), streamed in
:func:`eskin.device.simulate.accelerated_stream`'s batches as the live loop reads them; the
stack is the workspace's exported one (models/<scene>/stack.onnx), with params.yaml's
``live`` knobs. A two-contact stack detects no contact (it reports two on every frame):
its scene has no hour to score, and the stage says so.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from eskin.catalog import stack_path
from eskin.config import get_scene, load_params
from eskin.deploy.live import live_estimates
from eskin.deploy.stack import ExportedStack
from eskin.device.board import SimulatedBoard
from eskin.device.physics import skin_params
from eskin.device.simulate import accelerated_stream

GRACE_MS = 100  # a press's first 100 ms (and a release's) are not scored: hysteresis' time


@dataclass(frozen=True)
class Step:
    """From ``at_ms`` of board time on: the indenter (x, y, newtons; none: untouched) and
    the stretch (mm); ``tare``: ask live for a re-tare there."""

    at_ms: int
    press: tuple[int, int, float] | None
    stretch_mm: float
    kind: str  # untouched | press | sustained | stretch
    tare: bool = False


def script(settings, forces: list[float], rows: int, columns: int) -> list[Step]:
    """The hour: ``settings`` is bench/params.yaml's ``live_hour``."""
    rng = np.random.default_rng(settings.seed)
    gap, press = int(settings.untouched_s * 1000), int(settings.press_s * 1000)
    events: list[tuple[str, Any]] = [("press", None)] * settings.presses
    events += [("stretch", mm) for mm in settings.stretches_mm] + [("sustained", None)]
    order = rng.permutation(len(events))
    steps, t, stretch = [Step(0, None, 0.0, "untouched")], gap, 0.0
    forces = [f for f in forces if f > 0]
    for i in order:
        kind, mm = events[i]
        if kind == "stretch":
            stretch = float(mm)
            steps.append(Step(t, None, stretch, "stretch"))
            t += gap
            continue
        node = (int(rng.integers(1, rows + 1)), int(rng.integers(1, columns + 1)))
        newtons = float(rng.choice(forces))
        held = int(settings.sustained_s * 1000) if kind == "sustained" else press
        steps.append(Step(t, (*node, newtons), stretch, kind))
        t += held
        steps.append(Step(t, None, stretch, "untouched"))
        if kind == "sustained" and settings.retare_after_sustained:
            steps.append(Step(t + 1000, None, stretch, "untouched", tare=True))
        t += gap
    return steps


def run(scene: str, settings, params_path: Path = Path("params.yaml")) -> pd.DataFrame:
    """One row per estimate: the live record beside the script's truth at its frame."""
    params = load_params(params_path)
    scene_params = get_scene(params, scene, params_path)
    stack = ExportedStack.from_file(stack_path(scene))
    board = SimulatedBoard(skin_params(params.sim), skin=stack.skin,
                           rest_length_mm=float(params.acquire.rest_length_mm),
                           frame_period_ms=int(params.sim_board.frame_period_ms))
    steps = script(settings, list(scene_params.forces), stack.skin.rows, stack.skin.columns)
    end_ms = int(settings.minutes * 60_000)
    state = {"step": 0, "now": steps[0], "tare": False}
    seconds: list[float] = []

    def batches():
        for events in accelerated_stream(board, batch_frames=settings.batch_frames):
            t_ms = events[0].frame.t_ms
            if t_ms >= end_ms:
                return
            while state["step"] < len(steps) and steps[state["step"]].at_ms <= t_ms:
                step = steps[state["step"]]
                before = state["now"]
                if step.stretch_mm != before.stretch_mm:
                    board.handle(f"STRETCH {step.stretch_mm:g}".encode())
                if step.press != before.press:
                    board.handle(b"SIM CLEAR")
                    if step.press is not None:
                        board.handle("SIM PRESS {} {} {}".format(*step.press).encode())
                state["tare"] |= step.tare
                state["now"], state["step"] = step, state["step"] + 1
            truth.extend((f.frame.t_ms, state["now"]) for f in events)
            yield events

    def requests():
        asked, state["tare"] = ["tare"] if state["tare"] else [], False
        return asked

    truth: list[tuple[int, Step]] = []
    predict = stack.predict

    def timed(counts):
        start = time.perf_counter()
        out = predict(counts)
        seconds.append(time.perf_counter() - start)
        return out

    stack.predict = timed  # type: ignore[method-assign]
    records = [r for r in live_estimates(stack, batches(), settings=params.live,
                                         requests=requests) if "seq" in r]
    stack.predict = predict  # type: ignore[method-assign]
    at = dict(truth)
    rows = []
    for r in records:
        step = at[r["t_ms"]]
        rows.append({**{k: r[k] for k in ("t_ms", "contact", "x", "y", "force", "stretch")},
                     "kind": step.kind, "since_ms": r["t_ms"] - step.at_ms,
                     "true_x": step.press[0] if step.press else None,
                     "true_y": step.press[1] if step.press else None,
                     "true_force": step.press[2] if step.press else 0.0,
                     "true_stretch": 1 + step.stretch_mm / float(params.acquire.rest_length_mm)})
    frame = pd.DataFrame(rows)
    single = [float(np.median(_single_frame_latency(stack, board)))]
    frame.attrs.update(batch_seconds=seconds, single_frame_seconds=single,
                       steps=len(steps))
    return frame


def _single_frame_latency(stack: ExportedStack, board: SimulatedBoard) -> list[float]:
    """The ONNX stack on one frame at a time, as a robot loop that keeps up calls it."""
    frames = np.array([e.frame.counts for e in next(accelerated_stream(
        board, batch_frames=1000))], dtype=np.float64)
    out = []
    for row in frames:
        start = time.perf_counter()
        stack.predict(row[None, :])
        out.append(time.perf_counter() - start)
    return out


def score(frame: pd.DataFrame, batch_scores: dict[str, Any]) -> dict[str, Any]:
    """The hour's scores (issue 39's targets beside them)."""
    untouched = frame[frame["true_x"].isna() & (frame["since_ms"] >= GRACE_MS)]
    pressed = frame[frame["true_x"].notna() & (frame["since_ms"] >= GRACE_MS)]
    found = pressed[pressed["contact"]]
    sustained = frame[frame["kind"] == "sustained"]
    end = sustained[sustained["since_ms"] >= sustained["since_ms"].max() - 1000]
    flat = frame["true_stretch"] == frame["true_stretch"].min()
    untouched_flat = untouched[flat.loc[untouched.index]]
    stretched_at = frame.loc[~flat, "t_ms"].min() if (~flat).any() else np.inf
    pressed_flat = pressed[flat.loc[pressed.index]]
    found_flat = pressed_flat[pressed_flat["contact"]]
    before = frame[(frame["t_ms"] < stretched_at)]
    untouched_before = untouched[untouched["t_ms"] < stretched_at]
    pressed_before = before[before["true_x"].notna() & (before["since_ms"] >= GRACE_MS)]
    return {
        "frames": len(frame),
        "hours": round(float(frame["t_ms"].max() - frame["t_ms"].min()) / 3.6e6, 3),
        "phantom_share": _share(untouched["contact"]),
        "phantom_share_unstretched": _share(untouched_flat["contact"]),
        "phantom_share_stretched": _share(untouched[~flat.loc[untouched.index]]["contact"]),
        "untouched_frames": len(untouched),
        "phantom_share_before_first_stretch": _share(untouched_before["contact"]),
        "untouched_frames_before_first_stretch": len(untouched_before),
        "missed_share_before_first_stretch": _share(~pressed_before["contact"]),
        "missed_share": _share(~pressed["contact"]),
        "missed_share_unstretched": _share(~pressed_flat["contact"]),
        "location_accuracy_unstretched": _share((found_flat["x"] == found_flat["true_x"])
                                                & (found_flat["y"] == found_flat["true_y"])),
        "force_mae_n_unstretched": round(float(
            (found_flat["force"] - found_flat["true_force"]).abs().mean()), 4)
        if len(found_flat) else None,
        "pressed_frames": len(pressed),
        "location_accuracy": _share((found["x"] == found["true_x"])
                                    & (found["y"] == found["true_y"])),
        "x_accuracy": _share(found["x"] == found["true_x"]),
        "y_accuracy": _share(found["y"] == found["true_y"]),
        "force_mae_n": round(float((found["force"] - found["true_force"]).abs().mean()), 4)
        if len(found) else None,
        "sustained_detected_at_end": bool(len(end)) and bool(end["contact"].all()),
        "sustained_contact_share": _share(sustained[sustained["since_ms"] >= GRACE_MS]
                                          ["contact"]),
        "onnx_latency_ms_median": round(frame.attrs["single_frame_seconds"][0] * 1000, 3),
        "onnx_batch_ms_median": round(float(np.median(frame.attrs["batch_seconds"])) * 1000, 3),
        "batch_cv": batch_scores,
    }


def _share(values) -> float | None:
    values = np.asarray(values, dtype=bool)
    return round(float(values.mean()), 5) if len(values) else None


def batch_cv_scores(scene: str, scores_dir: Path = Path("reports/scores")) -> dict[str, Any]:
    """The trained stack's grouped-CV scores (mean ± fold sd), to set the live ones beside."""
    out: dict[str, Any] = {}
    for task, metric, targets in (("localise", "accuracy", ("x", "y")),
                                  ("force", "mae", ("force",))):
        path = scores_dir / scene / f"{task}.json"
        if not path.exists():
            continue
        grouped = json.loads(path.read_text()).get("grouped", {})
        for target in targets:
            if target in grouped:
                out[f"{target}_{metric}"] = [round(grouped[target][metric], 4),
                                             round(grouped[target][f"{metric}_std"], 4)]
    return out


def render(scene: str, result: dict[str, Any]) -> str:
    """The markdown table (reports/live_hour/<scene>.md)."""
    cv = result["batch_cv"]

    def pct(value):
        return "–" if value is None else f"{100 * value:.2f} %"

    def spread(name, scale=1.0, unit=""):
        if name not in cv:
            return "–"
        mean, sd = cv[name]
        return f"{mean * scale:.3g} ± {sd * scale:.2g}{unit}"

    rows = [
        ("phantom contacts, untouched frames", pct(result["phantom_share"]), "≤ 0.1 %"),
        ("… unstretched (λ = 1)", pct(result["phantom_share_unstretched"]), "≤ 0.1 %"),
        ("… stretched", pct(result["phantom_share_stretched"]), "≤ 0.1 %"),
        ("… before the first stretch change "
         f"({result['untouched_frames_before_first_stretch']} frames)",
         pct(result["phantom_share_before_first_stretch"]), "≤ 0.1 %"),
        ("missed contacts, pressed frames after 100 ms", pct(result["missed_share"]), "≤ 1 %"),
        ("… unstretched (λ = 1)", pct(result["missed_share_unstretched"]), "≤ 1 %"),
        ("… before the first stretch change", pct(result["missed_share_before_first_stretch"]),
         "≤ 1 %"),
        ("location (x and y right), detected frames", pct(result["location_accuracy"]),
         f"grouped CV x {spread('x_accuracy', 100, ' %')}, y {spread('y_accuracy', 100, ' %')}"),
        ("… unstretched (λ = 1)", pct(result["location_accuracy_unstretched"]), ""),
        ("force error (MAE), detected frames", f"{result['force_mae_n']} N",
         f"grouped CV {spread('force_mae', 1, ' N')}"),
        ("… unstretched (λ = 1)", f"{result['force_mae_n_unstretched']} N", ""),
        ("sustained press detected at its end", "yes" if result["sustained_detected_at_end"]
         else "no", "yes"),
        ("sustained press, frames in contact", pct(result["sustained_contact_share"]),
         "100 %"),
        ("ONNX latency, one frame, median", f"{result['onnx_latency_ms_median']} ms", "≤ 1 ms"),
    ]
    lines = [f"# Live hour: {scene}, {result['hours']} h of board time, "
             f"{result['frames']} frames",
             "", "| | live | target |", "|---|---|---|"]
    lines += [f"| {name} | {value} | {target} |" for name, value, target in rows]
    lines += ["", f"{result['untouched_frames']} untouched and {result['pressed_frames']} "
              f"pressed frames scored (a press's first {GRACE_MS} ms, and a release's, "
              "are not); script: " + result["script"] + "."]
    return "\n".join(lines)
