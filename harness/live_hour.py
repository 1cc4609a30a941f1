"""make bench's live hour (issue 39): the live stack on an hour of the simulated board's
stream, faster than real time, scored against the script's ground truth.

The script (:func:`script`, seeded) is untouched minutes; presses drawn from the scene's
own plan (a node or, for a two-contact scene, a pair, at its forces), each ramping up as a
hand press does; one sustained press; stretch changes. The board is the one `eskin live
--simulated` starts (params.yaml's sim and sim_board), streamed in
:func:`eskin.device.simulate.accelerated_stream`'s batches as the live loop reads them; the
stack is the workspace's exported one (models/<scene>/stack.onnx), with params.yaml's
``live`` knobs. A one-contact scene is scored on phantoms, misses, location and force
(:func:`score`); a two-contact scene's pressed frames are scored as the batch pairs are
(:func:`score_pairs`), and, where its stack counts contacts (a scene recorded with
``contact_counts``), its phantoms and misses as a one-contact scene's; a stack trained on
pairs alone reports two contacts on every frame, and detects none.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from eskin.catalog import PAIRS, PREDICTIONS_DIR, SCORES_DIR, scores_path, stack_path
from eskin.config.base import load_params
from eskin.config.params import Params
from eskin.config.scenes import get_scene
from eskin.data.plan import ScenePlan, plan_from_params
from eskin.deploy.live import live_estimates
from eskin.deploy.stack import ExportedStack, SkinStack
from eskin.device.board import SimulatedBoard
from eskin.device.simulate import accelerated_stream, live_board
from eskin.kinds import KINDS

# What live says of a frame, scored where its stack says it: whether a contact presses,
# how many ("contacts": a counting two-contact stack), each kind's positions and forces,
# the stretch.
ESTIMATES = ["contact", "contacts", *dict.fromkeys(column for kind in KINDS.values()
                                       for column in (*kind.node_columns, *kind.force_columns)),
             "stretch"]
GRACE_MS = 100  # a press's first 100 ms (and a release's) are not scored: hysteresis' time


Press = tuple[tuple[int, int, float], ...]  # the indenters: (x, y, newtons) each


@dataclass(frozen=True)
class Step:
    """From ``at_ms`` of board time on: the indenters (none: untouched) and the stretch
    (mm); ``tare``: ask live for a re-tare there."""

    at_ms: int
    press: Press
    stretch_mm: float
    kind: str  # untouched | press | sustained | stretch (the harder hour: also tap, long)
    tare: bool = False
    part: str = ""  # the harder hour's part it belongs to (harness/hard_hour.py)


def scene_presses(plan: ScenePlan) -> list[Press]:
    """The presses of the scene's own plan (its nodes or pairs, at its forces), each once."""
    presses = {tuple((c.x, c.y, c.force) for c in condition.contacts if c.touches)
               for condition in plan.conditions}
    return sorted(presses - {()})


def script(settings, plan: ScenePlan, rest_length_mm: float) -> list[Step]:
    """The hour: ``settings`` is bench/params.yaml's ``live_hour``; the presses are drawn
    from the scene's plan (one or two contacts, as its kind), the stretches are the
    bench's that the scene was trained on. The sustained press is one of the plan's
    heaviest: it checks that following the baseline does not absorb a long contact, which
    a press the stack cannot see at all would not show (light presses are among the
    single ones)."""
    rng = np.random.default_rng(settings.seed)
    gap, press = int(settings.untouched_s * 1000), int(settings.press_s * 1000)
    trained_mm = [(float(s) - 1.0) * rest_length_mm for s in {c.stretch for c in plan.conditions}]
    stretches = [mm for mm in settings.stretches_mm
                 if any(abs(mm - known) < 1e-3 for known in trained_mm)]
    events: list[tuple[str, Any]] = [("press", None)] * settings.presses
    events += [("stretch", mm) for mm in stretches] + [("sustained", None)]
    order = rng.permutation(len(events))
    steps, t, stretch = [Step(0, (), 0.0, "untouched")], gap, 0.0
    presses = scene_presses(plan)
    heaviest = max(sum(f for _, _, f in p) for p in presses)
    sustained = [p for p in presses if sum(f for _, _, f in p) == heaviest]
    for i in order:
        kind, mm = events[i]
        if kind == "stretch":
            stretch = float(mm)
            steps.append(Step(t, (), stretch, "stretch"))
            t += gap
            continue
        choices = sustained if kind == "sustained" else presses
        chosen = choices[int(rng.integers(len(choices)))]
        held = int(settings.sustained_s * 1000) if kind == "sustained" else press
        steps.append(Step(t, chosen, stretch, kind))
        t += held
        steps.append(Step(t, (), stretch, "untouched"))
        if kind == "sustained" and settings.retare_after_sustained:
            steps.append(Step(t + 1000, (), stretch, "untouched", tare=True))
        t += gap
    return steps


def run(scene: str, settings, params_path: Path = Path("params.yaml"), *,
        steps_of: Callable[[ScenePlan, float], tuple[list[Step], int]] | None = None,
        stack_kind: str = "onnx") -> pd.DataFrame:
    """One row per estimate: the live record beside the script's truth at its frame.
    ``steps_of`` (plan, rest length in mm) gives another script and its end in ms of board
    time (default: :func:`script`, ``settings.minutes`` long); ``stack_kind``: the exported
    ``onnx`` stack, or the ``scikit-learn`` one dvc.lock records (slower per batch)."""
    params = load_params(Params, params_path)
    plan = plan_from_params(scene, get_scene(params, scene, params_path))
    stack = SkinStack.from_workspace(scene) if stack_kind == "scikit-learn" else \
        ExportedStack.from_file(stack_path(scene))
    if settings.drift_offset_pf is not None:  # the hour's own drift: the sim's is the data's
        params = params.model_copy(update={"sim": params.sim.model_copy(
            update={"drift_offset_pf": float(settings.drift_offset_pf)})})
    board = live_board(params, stack.skin)
    rest_length_mm = float(params.acquire.rest_length_mm)
    if steps_of is None:
        steps, end_ms = script(settings, plan, rest_length_mm), int(settings.minutes * 60_000)
    else:
        steps, end_ms = steps_of(plan, rest_length_mm)
    # A step acts from the first frame the board reads after it was given (between two
    # batches): the truth, and a step's "since", follow the board, not the script's clock.
    state = {"step": 0, "now": steps[0], "began": 0, "tare": False, "pending": False}
    seconds: list[float] = []

    def batches():
        for events in accelerated_stream(board, batch_frames=settings.batch_frames):
            t_ms = events[0].frame.t_ms
            if t_ms >= end_ms:
                return
            if state["pending"]:
                state["began"], state["pending"] = t_ms, False
            truth.extend((f.frame.t_ms, (state["now"], state["began"])) for f in events)
            yield events
            ahead = events[-1].frame.t_ms + board.frame_period_ms  # the next frame's time
            while state["step"] < len(steps) and steps[state["step"]].at_ms <= ahead:
                step = steps[state["step"]]
                before = state["now"]
                if step.stretch_mm != before.stretch_mm:
                    board.handle(f"STRETCH {step.stretch_mm:g}".encode())
                if step.press != before.press:
                    board.handle(b"SIM CLEAR")
                    for x, y, newtons in step.press:
                        board.handle(f"SIM PRESS {x} {y} {newtons} "
                                     f"{settings.press_ramp_ms:g}".encode())
                state["tare"] |= step.tare
                state["now"], state["step"], state["pending"] = step, state["step"] + 1, True

    def requests():
        asked, state["tare"] = ["tare"] if state["tare"] else [], False
        return asked

    truth: list[tuple[int, tuple[Step, int]]] = []
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
    estimated = [c for c in ESTIMATES if c in stack.columns or c == "contact"]
    rows = []
    for r in records:
        step, began = at[r["t_ms"]]
        truths = {}
        if len(plan.conditions[0].contacts) == 1:
            (x, y, newtons), = step.press or ((None, None, 0.0),)
            truths = {"true_x": x, "true_y": y, "true_force": newtons}
        else:
            for i, (x, y, newtons) in enumerate(step.press or ((None, None, 0.0),) * 2, 1):
                truths.update({f"true_x{i}": x, f"true_y{i}": y, f"true_force{i}": newtons})
        rows.append({**{k: r.get(k) for k in estimated}, "t_ms": r["t_ms"],
                     "kind": step.kind, "part": step.part, "since_ms": r["t_ms"] - began,
                     "pressed": bool(step.press), **truths,
                     "true_stretch": 1 + step.stretch_mm / rest_length_mm})
    frame = pd.DataFrame(rows)
    single = [float(np.median(_single_frame_latency(stack, board)))]
    frame.attrs.update(batch_seconds=seconds, single_frame_seconds=single,
                       steps=len(steps), frame_period_ms=board.frame_period_ms,
                       stretches_mm=[s.stretch_mm for s in steps if s.kind == "stretch"])
    return frame


def _single_frame_latency(stack: ExportedStack | SkinStack,
                          board: SimulatedBoard) -> list[float]:
    """The stack on one frame at a time, as a robot loop that keeps up calls it."""
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
    untouched = frame[~frame["pressed"] & (frame["since_ms"] >= GRACE_MS)]
    pressed = frame[frame["pressed"] & (frame["since_ms"] >= GRACE_MS)]
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
    pressed_before = before[before["pressed"] & (before["since_ms"] >= GRACE_MS)]
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


def says_contact(frame: pd.DataFrame) -> bool:
    """Whether live said, frame by frame, if a contact pressed (its hysteresis' verdict):
    a one-contact stack's detector, or a two-contact stack that counts (its scene was
    recorded with contact_counts). A stack trained on pairs alone says none."""
    return "contact" in frame and bool(frame["contact"].notna().any())


def score_pairs(frame: pd.DataFrame, batch_scores: dict[str, Any]) -> dict[str, Any]:
    """A two-contact scene's hour: the frames of its pair presses scored as the batch pairs
    are (:mod:`eskin.evaluation.pairs`: a pair right as a set, each contact's force against
    the force predicted for the contact matched to it). Where its stack counts contacts
    (its plan also presses one node, so the script does too), also phantoms (untouched
    frames it counted any on), misses (pressed frames it counted none on) and the count
    on pressed frames. A stack trained on pairs alone reports two on every frame: those
    are None."""
    from eskin.evaluation.pairs import CONTACTS, pair_outcomes, pair_scores

    pressed = frame[frame["pressed"] & (frame["since_ms"] >= GRACE_MS)]
    untouched = frame[~frame["pressed"] & (frame["since_ms"] >= GRACE_MS)]
    counts = says_contact(frame)
    contact = frame["contact"].fillna(False).astype(bool) if counts else None
    # how many the script pressed: a one-node press has no second contact
    true_count = sum((pressed.get(f"true_force{i}", pd.Series(0.0, index=pressed.index))
                      .fillna(0.0) > 0).astype(int) for i in CONTACTS)
    pairs = pressed[true_count == len(CONTACTS)]
    named = pd.DataFrame({
        **{f"{a}{i}_true": pairs[f"true_{a}{i}"].astype(float) for a in ("x", "y", "force")
           for i in CONTACTS},
        # a contact a counting stack does not place (it counted fewer) is node 0, 0 N
        **{f"{a}{i}_pred": pairs[f"{a}{i}"].astype(float).fillna(0.0)
           for a in ("x", "y", "force") for i in CONTACTS}})
    scores = pair_scores(pair_outcomes(named)) if len(named) else {}
    sustained = pairs[pairs["kind"] == "sustained"]
    sustained_scores = pair_scores(pair_outcomes(named.loc[sustained.index])) \
        if len(sustained) else {}
    return {
        "frames": len(frame),
        "hours": round(float(frame["t_ms"].max() - frame["t_ms"].min()) / 3.6e6, 3),
        "pressed_frames": len(pressed),
        "pair_frames": len(pairs),
        "pair_accuracy": _round(scores.get("pair_accuracy")),
        "contact_accuracy": _round(scores.get("contact_accuracy")),
        "force_mae_n": _round(scores.get("force_mae")),
        "sustained_pair_accuracy": _round(sustained_scores.get("pair_accuracy")),
        "sustained_force_mae_n": _round(sustained_scores.get("force_mae")),
        "counts_contacts": counts,
        "untouched_frames": len(untouched),
        "phantom_share": _share(contact[untouched.index]) if counts else None,
        "missed_share": _share(~contact[pressed.index]) if counts else None,
        "count_right_share": _share(pressed["contacts"] == true_count) if counts else None,
        "onnx_latency_ms_median": round(frame.attrs["single_frame_seconds"][0] * 1000, 3),
        "onnx_batch_ms_median": round(float(np.median(frame.attrs["batch_seconds"])) * 1000, 3),
        "batch_cv": batch_scores,
    }


def _round(value) -> float | None:
    return None if value is None else round(float(value), 5)


def _share(values) -> float | None:
    values = np.asarray(values, dtype=bool)
    return round(float(values.mean()), 5) if len(values) else None


def write_report(directory: Path, scene: str, result: dict[str, Any], text: str) -> None:
    """An hour's result as ``<directory>/<scene>.json`` and its table as ``.md``; printed."""
    directory.mkdir(parents=True, exist_ok=True)
    (directory / f"{scene}.json").write_text(json.dumps(result, indent=2) + "\n")
    (directory / f"{scene}.md").write_text(text + "\n")
    print(text)


def write_skipped_import(directory: Path, scene: str, title: str) -> None:
    """An imported scene's report: no hour, and why."""
    reason = ("an imported scene has no plan to script presses from, and no simulated "
              "skin to stream.")
    write_report(directory, scene, {"scene": scene, "skipped": reason},
                 f"# {title}: {scene}\n\nSkipped: {reason}")


def batch_cv_scores(scene: str, scores_dir: Path = SCORES_DIR,
                    predictions_dir: Path = PREDICTIONS_DIR) -> dict[str, Any]:
    """The trained stack's conditions-CV scores (mean ± fold sd), to set the live ones
    beside. A one-contact scene's from its tasks' predictions (:func:`cv_scores_of`): x
    and y right, and the force error on pressed rows; and the same on its light edge and
    corner presses alone, under ``light_edges`` (:func:`light_edge_rows`), which the
    harder hour's parts of such presses are set beside. A two-contact scene's pairs from
    where the report writes them."""
    out: dict[str, Any] = {}
    pairs = scores_path(scene, PAIRS)
    if pairs.exists():
        held_out = json.loads(pairs.read_text()).get("conditions", {})
        for name in ("pair_accuracy", "force_mae"):
            if name in held_out:
                out[name] = [round(held_out[name], 4), round(held_out[f"{name}_std"], 4)]
    localise, force = (predictions_dir / scene / f"{task}.parquet"
                       for task in ("localise", "force"))
    localised = pd.read_parquet(localise) if localise.exists() else None
    weighed = pd.read_parquet(force) if force.exists() else None
    out.update(cv_scores_of(localised, weighed))
    paired = localised is not None and {"x2_true", "y2_true"} <= set(localised)
    light = (pair_cv_scores_of if paired else cv_scores_of)(localised, weighed,
                                                            light_edge_rows)
    if light:
        out[LIGHT_EDGES] = light
    return out


LIGHT_EDGES = "light_edges"  # batch_cv's key of the light edge and corner presses' scores


def light_edge_rows(predictions: pd.DataFrame) -> pd.Series:
    """The rows of a task's predictions whose every contact presses at the plan's lightest
    force on an edge or corner node (its first or last row or column): the harder hour's
    light edge and long presses, whose batch scores are below the average press's
    (single_force, conditions CV: x right on 95.4 % of them, 99.1 % of all presses;
    two_force: pairs right on 75.3 % of its light edge pairs, 91.3 % of all pairs)."""
    contacts = [("x", "y", "force")] if "force" in predictions else \
        [(f"x{i}", f"y{i}", f"force{i}") for i in (1, 2)]
    if not {name for contact in contacts for name in contact} <= set(predictions):
        return pd.Series(False, index=predictions.index)
    # every contact that presses, one a row: the plan's lightest force and its edge lines
    presses = pd.concat([predictions[list(contact)].set_axis(["x", "y", "force"], axis=1)
                         for contact in contacts])
    presses = presses[presses["force"] > 0]
    if presses.empty:
        return pd.Series(False, index=predictions.index)
    rows = pd.Series(True, index=predictions.index)
    for x, y, force in contacts:
        on_edge = (predictions[x].isin([presses["x"].min(), presses["x"].max()])
                   | predictions[y].isin([presses["y"].min(), presses["y"].max()]))
        rows &= (predictions[force] == presses["force"].min()) & on_edge
    return rows


def pair_cv_scores_of(localised: pd.DataFrame, weighed: pd.DataFrame | None,
                      rows: Callable[[pd.DataFrame], pd.Series],
                      scheme: str = "conditions") -> dict[str, list[float]]:
    """A two-contact stack's CV scores under ``scheme`` on the ``rows`` kept, scored as the
    report scores its pairs (:func:`eskin.evaluation.pairs.score_pairs`): pairs right and
    the matched force error, each mean and fold SD."""
    from eskin.evaluation.pairs import score_pairs

    kept = localised[(localised["scheme"] == scheme) & rows(localised)]
    if kept.empty:
        return {}
    scores = score_pairs(kept, weighed).get(scheme, {})
    return {name: [round(scores[name], 4), round(scores[f"{name}_std"], 4)]
            for name in ("pair_accuracy", "force_mae") if name in scores}


def cv_scores_of(localised: pd.DataFrame | None, weighed: pd.DataFrame | None,
                 rows: Callable[[pd.DataFrame], pd.Series] | None = None,
                 scheme: str = "conditions") -> dict[str, list[float]]:
    """A one-contact stack's CV scores under ``scheme`` as live scores its own, each mean
    and SD over folds (the SD as the training scores give it: ddof 0): x and y right, from
    the localise task's predictions ``localised``; the force error on pressed rows (true
    force above 0), from the force task's ``weighed``. The force task's own MAE
    (scores/<scene>/force.json) also counts its untouched rows, whose force of 0 is
    near-free (single_force: 0.254 N over every row, 0.338 N over the pressed ones): set
    beside it, a live press looked worse than it was. ``rows``: the rows kept (a mask of
    a frame of predictions); a task without predictions, or a two-contact task, is left
    out."""
    def kept(frame: pd.DataFrame, predicted: str) -> pd.DataFrame:
        frame = frame[(frame["scheme"] == scheme) & frame[predicted].notna()]
        return frame[rows(frame)] if rows is not None else frame

    def spread(per_row: pd.Series, folds: pd.Series) -> list[float]:
        per_fold = per_row.groupby(folds).mean()
        return [round(float(per_fold.mean()), 4), round(float(per_fold.std(ddof=0)), 4)]

    out: dict[str, list[float]] = {}
    if localised is not None and {"x_pred", "y_pred"} <= set(localised):
        found = kept(localised, "x_pred")
        if not found.empty:
            for axis in ("x", "y"):
                out[f"{axis}_accuracy"] = spread(found[f"{axis}_pred"] == found[f"{axis}_true"],
                                                 found["fold"])
    if weighed is not None and "force_true" in weighed:
        pressed = kept(weighed, "force_pred")
        pressed = pressed[pressed["force_true"] > 0]
        if not pressed.empty:
            out["force_mae"] = spread((pressed["force_pred"].astype(float)
                                       - pressed["force_true"]).abs(), pressed["fold"])
    return out


def render(scene: str, result: dict[str, Any]) -> str:
    """The markdown table (reports/live_hour/<scene>.md)."""
    if "pair_accuracy" in result:
        return _render_pairs(scene, result)
    pct = _pct

    def spread(name, scale=1.0, unit=""):
        return _spread(result["batch_cv"], name, scale, unit)

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
         f"conditions CV x {spread('x_accuracy', 100, ' %')}, y {spread('y_accuracy', 100, ' %')}"),
        ("… unstretched (λ = 1)", pct(result["location_accuracy_unstretched"]), ""),
        ("force error (MAE), detected frames", f"{result['force_mae_n']} N",
         f"conditions CV, pressed rows {spread('force_mae', 1, ' N')}"),
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


def _pct(value) -> str:
    return "–" if value is None else f"{100 * value:.2f} %"


def _spread(cv: dict[str, Any], name: str, scale: float = 1.0, unit: str = "",
            prefix: str = "") -> str:
    """A batch score from :func:`batch_cv_scores` as mean ± fold sd, or – without it."""
    if name not in cv:
        return "–"
    mean, sd = cv[name]
    return f"{prefix}{mean * scale:.3g} ± {sd * scale:.2g}{unit}"


def _render_pairs(scene: str, result: dict[str, Any]) -> str:
    pct = _pct

    def spread(name, scale=1.0, unit=""):
        return _spread(result["batch_cv"], name, scale, unit, prefix="conditions CV ")

    counted = bool(result.get("counts_contacts"))
    rows = [
        ("phantom contacts, untouched frames", pct(result["phantom_share"]), "≤ 0.1 %"),
        ("missed contacts, pressed frames after 100 ms", pct(result["missed_share"]),
         "≤ 1 %"),
        ("count right (1 or 2), pressed frames", pct(result["count_right_share"]), ""),
    ] if counted else []
    rows += [
        ("pairs right (both contacts, as a set), pair frames",
         pct(result["pair_accuracy"]), spread("pair_accuracy", 100, " %")),
        ("contacts right", pct(result["contact_accuracy"]), ""),
        ("force error (MAE), per contact", f"{result['force_mae_n']} N",
         spread("force_mae", 1, " N")),
        ("sustained press: pairs right", pct(result["sustained_pair_accuracy"]), ""),
        ("sustained press: force error", f"{result['sustained_force_mae_n']} N", ""),
        ("ONNX latency, one frame, median", f"{result['onnx_latency_ms_median']} ms", "≤ 1 ms"),
    ]
    lines = [f"# Live hour: {scene}, {result['hours']} h of board time, "
             f"{result['frames']} frames", "",
             "Two contacts, counted: the stack says how many press (its scene was "
             "recorded with contact_counts), and a frame it counts none on is untouched."
             if counted else
             "Two contacts: the stack reports two on every frame and detects none, so "
             "phantoms and misses are not scored; the pressed frames are.", "",
             "| | live | target or batch |", "|---|---|---|"]
    lines += [f"| {name} | {value} | {target} |" for name, value, target in rows]
    scored = (f"{result['untouched_frames']} untouched and " if counted else "") + \
        f"{result['pressed_frames']} pressed frames scored ({result['pair_frames']} of " \
        "them of pairs)"
    lines += ["", f"{scored} (a press's first {GRACE_MS} ms, and a release's, are not); "
              "script: " + result["script"] + "."]
    return "\n".join(lines)
