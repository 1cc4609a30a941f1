"""The harder hour's script and scoring (harness/hard_hour.py), without a pipeline: every
part is scripted as bench/params.yaml says, its targets are computed from the frames, and a
part that misses one is judged MISSED. The README quotes the bench's table as written."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import ROOT

from eskin.config.base import BENCH_PARAMS, load_params, sections
from eskin.data.plan import single_force_plan, two_force_plan
from harness.hard_hour import (
    PARTS,
    WHOLE,
    edge_presses,
    hard_script,
    mixed_reference,
    quoted_in_readme,
    render,
    score_hard,
    table_of,
)
from harness.live_hour import LIGHT_EDGES, batch_cv_scores, cv_scores_of, light_edge_rows
from harness.params import HardHour

REST_MM = 101.0  # params.yaml's acquire.rest_length_mm
STRETCHES = [1.0, 1.07921, 1.15842]
LIGHT = 1.2936


@pytest.fixture(scope="module")
def settings():
    return load_params(sections(BENCH_PARAMS, hard_hour=HardHour),
                       ROOT / BENCH_PARAMS).hard_hour


def one_contact_plan():
    return single_force_plan("single_force", STRETCHES, [0.0, LIGHT, 3.2536, 5.2136], 1)


def test_every_part_is_scripted_as_its_settings_say(settings):
    plan = one_contact_plan()
    steps, end_ms = hard_script(settings, plan, REST_MM)
    assert [p for p in PARTS if any(s.part == p for s in steps)] == list(PARTS)
    assert [s.part for s in steps] == sorted((s.part for s in steps), key=PARTS.index)
    assert all(a.at_ms < b.at_ms for a, b in zip(steps, steps[1:], strict=False))
    duration = {id(s): b.at_ms - s.at_ms for s, b in zip(steps, [*steps[1:], None], strict=False)
                if b is not None}
    trained = sorted({round((s - 1) * REST_MM, 3) for s in STRETCHES})

    light = [s for s in steps if s.part == "light_edges" and s.press]
    # the 36 edge and corner nodes of a 10 x 10 skin at the lightest force, at each stretch
    assert len(edge_presses(plan)) == 36
    assert sorted((s.stretch_mm, s.press) for s in light) == sorted(
        (mm, p) for mm in trained for p in edge_presses(plan))
    assert all(duration[id(s)] == settings.light_press_s * 1000 for s in light)

    held = [s for s in steps if s.part == "held_through_stretch" and s.press]
    assert len(held) == 2 * settings.held_presses
    for first, second in zip(held[::2], held[1::2], strict=True):
        assert first.press == second.press and first.stretch_mm != second.stretch_mm
        assert duration[id(first)] + duration[id(second)] == settings.held_press_s * 1000

    taps = [s for s in steps if s.kind == "tap"]
    assert len(taps) == settings.taps
    assert all(duration[id(s)] == settings.tap_ms for s in taps)

    long = [s for s in steps if s.kind == "long"]
    assert [duration[id(s)] / 60_000 for s in long] == settings.long_presses_min
    assert long[0].stretch_mm == max(trained) and all(s.press in edge_presses(plan)
                                                      for s in long)
    last = steps[-1]
    assert (last.part, last.press, last.stretch_mm) == ("untouched", (), max(trained))
    assert end_ms - last.at_ms == settings.untouched_min * 60_000


def test_a_two_contact_plan_presses_light_pairs_on_the_edge_at_its_one_stretch(settings):
    plan = two_force_plan("two_force", [1.0], [LIGHT, 3.2536], [1, 6, 10], [1, 6, 10], 1)
    steps, _ = hard_script(settings, plan, REST_MM)
    light = [s.press for s in steps if s.part == "light_edges" and s.press]
    assert len(light) == 28  # the pairs of the 8 edge nodes of the 3 x 3 grid
    assert all(len(p) == 2 and all(f == LIGHT and (6, 6) != (x, y) for x, y, f in p)
               for p in light)
    assert not any(s.part == "held_through_stretch" for s in steps)  # trained at one


def frame_of(parts: list[tuple[str, str, bool, int, list[bool]]]) -> pd.DataFrame:
    """A live frame: per segment (part, kind, pressed, frames, contact each), 12 ms frames,
    the press at node (3, 4) at 2 N, read right at 2.1 N."""
    rows, t = [], 0
    for part, kind, pressed, _frames, contact in parts:
        for i, c in enumerate(contact):
            rows.append({"contact": c, "x": 3.0 if c else np.nan, "y": 4.0 if c else np.nan,
                         "force": 2.1 if c else np.nan, "t_ms": t, "kind": kind,
                         "part": part, "since_ms": 12 * i, "pressed": pressed,
                         "true_x": 3.0 if pressed else np.nan,
                         "true_y": 4.0 if pressed else np.nan,
                         "true_force": 2.0 if pressed else 0.0})
            t += 12
    frame = pd.DataFrame(rows)
    frame.attrs.update(frame_period_ms=12, single_frame_seconds=[0.0004])
    return frame


CV = {"x_accuracy": [0.99, 0.005], "y_accuracy": [0.99, 0.008], "force_mae": [0.25, 0.035]}


def test_the_targets_are_computed_from_the_frames_and_a_miss_is_stated(settings):
    frame = frame_of([
        # taps: every frame seen, then a phantom of 150 frames (1.8 s) after the release
        ("taps", "tap", True, 20, [True] * 20),
        ("taps", "untouched", False, 400, [True] * 150 + [False] * 250),
        # a long press held throughout, its force 0.1 N off, then clean
        ("long_presses", "long", True, 500, [True] * 500),
        ("long_presses", "untouched", False, 500, [False] * 500),
        # untouched, clean but one frame
        ("untouched", "untouched", False, 1000, [False] * 999 + [True]),
    ])
    result = score_hard(frame, CV, settings.targets)
    taps, long, untouched = (result["parts"][p] for p in ("taps", "long_presses", "untouched"))
    # after 100 ms (from the 9th frame of 12 ms): 391 untouched frames, 141 phantom
    assert taps["untouched_frames"] == 391
    assert taps["phantom_share"] == pytest.approx(141 / 391, abs=1e-5)
    assert taps["longest_phantom_s"] == pytest.approx(1.8)
    assert taps["verdicts"] == {"phantom": False, "longest_phantom": False, "missed": True,
                                "location": True, "force": True}
    assert not taps["met"]
    assert long["held_share"] == 1.0 and long["met"]
    assert long["force_mae_n"] == pytest.approx(0.1)
    assert untouched["phantom_share"] == pytest.approx(1 / 991, abs=1e-5)
    assert untouched["verdicts"] == {"phantom": False, "longest_phantom": True}
    whole = result["parts"][WHOLE]
    assert whole["presses"] == 2 and whole["presses_never_seen"] == 0
    table = render("single_force", {"scene": "single_force", **result, "script": "a test"})
    assert "| taps | 1 (0) | **36.06 %** | **1.8 s** |" in table
    assert "MISSED: phantom, longest phantom" in table
    assert "| long presses, and after | 1 (0) |" in table and "| met |" in table


def test_a_press_never_seen_and_a_location_outside_the_spread_are_missed(settings):
    frame = frame_of([
        ("light_edges", "press", True, 100, [False] * 100),
        ("light_edges", "untouched", False, 100, [False] * 100),
        ("light_edges", "press", True, 100, [True] * 100),
        ("light_edges", "untouched", False, 100, [False] * 100),
    ])
    frame.loc[frame.index[200:300], "x"] = 5.0  # the second press read at the wrong node
    part = score_hard(frame, CV, settings.targets)["parts"]["light_edges"]
    assert (part["presses"], part["presses_never_seen"]) == (2, 1)
    assert part["missed_share"] == pytest.approx(0.5, abs=0.01)
    assert part["x_accuracy"] == 0.0
    assert part["verdicts"]["missed"] is False and part["verdicts"]["location"] is False
    assert part["verdicts"]["phantom"] is True


def test_the_readme_quotes_the_benchs_table_as_written():
    report = ROOT / "reports" / "hard_hour" / "single_force.md"
    if not report.exists():
        pytest.skip("reports/hard_hour/single_force.md is missing: `dvc checkout` first")
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert quoted_in_readme(readme) == table_of(report.read_text(encoding="utf-8")), (
        "README.md's harder-hour table is not the bench's: `python -m harness.hard_hour`")


def test_the_readme_markers_hold_a_table():
    readme = Path(ROOT / "README.md").read_text(encoding="utf-8")
    assert quoted_in_readme(readme).startswith("| part |")


def test_live_force_is_set_beside_the_pressed_rows_cv_error_not_every_rows():
    # Two folds; untouched rows (true force 0) predicted right, pressed rows 0.4 N off in
    # fold 0 and 0.6 N in fold 1; a row no fold tested (NaN) is left out. Over every row
    # the MAE is half that: live, which scores pressed frames, would look twice as bad.
    rows = []
    for fold, error in ((0, 0.4), (1, 0.6)):
        rows += [{"scheme": "conditions", "fold": fold, "force_true": 0.0, "force_pred": 0.0}] * 4
        rows += [{"scheme": "conditions", "fold": fold, "force_true": 3.0,
                  "force_pred": 3.0 + error}] * 4
        rows += [{"scheme": "stratified", "fold": fold, "force_true": 3.0, "force_pred": 9.0}]
    rows.append({"scheme": "conditions", "fold": -1, "force_true": 3.0, "force_pred": np.nan})
    predictions = pd.DataFrame(rows)
    assert cv_scores_of(None, predictions) == {"force_mae": pytest.approx([0.5, 0.1])}
    every_row = predictions[(predictions["scheme"] == "conditions")
                            & predictions["force_pred"].notna()]
    assert (every_row["force_pred"] - every_row["force_true"]).abs().mean() == pytest.approx(0.25)
    assert cv_scores_of(None, predictions.drop(columns="force_true")) == {}
    assert cv_scores_of(None, predictions[predictions["force_true"] == 0]) == {}


def predictions_of(rows: list[tuple[int, float, float, float, float, float]]) -> pd.DataFrame:
    """Conditions-CV predictions of a 10 x 10 skin's localise and force tasks, in one
    frame: (fold, x, y, force, x predicted, force predicted) a row; y is read right."""
    frame = pd.DataFrame(rows, columns=["fold", "x", "y", "force", "x_pred", "force_pred"])
    return frame.assign(scheme="conditions", x_true=frame["x"], y_true=frame["y"],
                        y_pred=frame["y"], force_true=frame["force"])


def test_the_light_edge_parts_are_set_beside_the_batchs_light_edge_presses(tmp_path):
    # Light (1.29 N) presses on edge and corner nodes: x right on half of them; heavier or
    # inner presses: always. The light edge class is judged by its own batch scores.
    predictions = predictions_of([
        (0, 1, 5, 1.29, 2, 1.29), (0, 10, 10, 1.29, 10, 1.29),  # light, edge: one wrong
        (1, 5, 1, 1.29, 4, 1.79), (1, 1, 1, 1.29, 1, 1.29),     # light, edge: one wrong
        (0, 5, 5, 1.29, 5, 1.29), (1, 1, 5, 3.25, 1, 3.25),     # light inner, heavy edge
        (0, 6, 6, 5.21, 6, 5.21), (1, 6, 6, 5.21, 6, 5.21),
        (0, 0, 0, 0.0, np.nan, 0.0), (1, 0, 0, 0.0, np.nan, 0.0)])  # untouched
    assert light_edge_rows(predictions).tolist() == [True] * 4 + [False] * 6
    light = cv_scores_of(predictions, predictions, light_edge_rows)
    assert light["x_accuracy"] == [0.5, 0.0] and light["y_accuracy"] == [1.0, 0.0]
    assert light["force_mae"] == pytest.approx([0.125, 0.125])  # fold 0: 0 N, fold 1: 0.25 N
    (tmp_path / "s").mkdir()
    predictions.to_parquet(tmp_path / "s" / "localise.parquet")
    predictions.to_parquet(tmp_path / "s" / "force.parquet")
    cv = batch_cv_scores("s", tmp_path, tmp_path)
    assert cv["x_accuracy"] == pytest.approx([0.75, 0.0]) and cv[LIGHT_EDGES] == light


def test_a_two_contact_scenes_light_edge_parts_are_set_beside_its_light_edge_pairs(tmp_path):
    # Pairs (fold, (x1, y1, f1), (x2, y2, f2), the second contact predicted at x2p): both
    # light on edge nodes, one wrong a fold; a light pair with an inner contact, a heavy
    # edge pair and a one-contact row (a counting scene's) are not of the class.
    rows = [(0, (1, 1, 1.29), (10, 10, 1.29), 9), (0, (1, 10, 1.29), (10, 1, 1.29), 10),
            (1, (1, 1, 1.29), (10, 1, 1.29), 10), (1, (1, 10, 1.29), (10, 10, 1.29), 6),
            (0, (1, 1, 1.29), (6, 6, 1.29), 6), (1, (1, 1, 3.25), (10, 10, 3.25), 10),
            (1, (1, 1, 1.29), (0, 0, 0.0), 0)]
    localised = pd.DataFrame([
        {"scheme": "conditions", "fold": fold, "trial": i, "sample": 0,
         "x1": a[0], "y1": a[1], "force1": a[2], "x2": b[0], "y2": b[1], "force2": b[2],
         "x1_true": a[0], "y1_true": a[1], "x2_true": b[0], "y2_true": b[1],
         "x1_pred": a[0], "y1_pred": a[1], "x2_pred": x2p, "y2_pred": b[1]}
        for i, (fold, a, b, x2p) in enumerate(rows)])
    weighed = localised[["scheme", "fold", "trial", "sample", "x1", "y1", "x2", "y2",
                         "force1", "force2"]].assign(
        force1_true=localised["force1"], force2_true=localised["force2"],
        force1_pred=localised["force1"] + 0.1, force2_pred=localised["force2"])
    assert light_edge_rows(localised).tolist() == [True] * 4 + [False] * 3
    (tmp_path / "p").mkdir()
    localised.to_parquet(tmp_path / "p" / "localise.parquet")
    weighed.to_parquet(tmp_path / "p" / "force.parquet")
    light = batch_cv_scores("p", tmp_path, tmp_path)[LIGHT_EDGES]
    assert light["pair_accuracy"] == pytest.approx([0.5, 0.0])
    assert light["force_mae"] == pytest.approx([0.05, 0.0])  # 0.1 N on one of two contacts


def test_a_light_edge_part_is_judged_against_its_class_and_the_rest_against_all(settings):
    frame = frame_of([
        ("light_edges", "press", True, 100, [True] * 100),
        ("light_edges", "untouched", False, 100, [False] * 100),
        ("taps", "tap", True, 100, [True] * 100),
        ("taps", "untouched", False, 100, [False] * 100),
    ])
    frame["x"] = np.where(np.arange(len(frame)) % 10 == 0, 5.0, frame["x"])  # 90 % right
    cv = {**CV, LIGHT_EDGES: {"x_accuracy": [0.9, 0.02], "y_accuracy": [0.9, 0.02],
                              "force_mae": [0.5, 0.1]}}
    parts = score_hard(frame, cv, settings.targets)["parts"]
    assert parts["light_edges"]["verdicts"]["location"] is True   # beside the class's 90 %
    assert parts["taps"]["verdicts"]["location"] is False         # beside every press's
    assert parts[WHOLE]["verdicts"]["location"] is False
    without = score_hard(frame, CV, settings.targets)["parts"]["light_edges"]
    assert without["verdicts"]["location"] is False  # no class scores: every press's
    table = render("single_force", {"scene": "single_force", **score_hard(
        frame, cv, settings.targets), "script": "a test"})
    assert "light edge and long press parts are set beside (the whole script: each part's, " \
           "weighted by the frames it located): x 90 ± 2 %" in table


def test_the_whole_script_is_set_beside_the_mix_of_its_parts_references(settings):
    # 91 located frames of light edge presses (class: 90 % right) and 291 of taps (every
    # press: 99 %): the whole's reference is their mean weighted by those frames.
    frame = frame_of([
        ("light_edges", "press", True, 100, [True] * 100),
        ("taps", "tap", True, 300, [True] * 300),
    ])
    cv = {**CV, LIGHT_EDGES: {"x_accuracy": [0.9, 0.02], "y_accuracy": [0.9, 0.02],
                              "force_mae": [0.5, 0.1]}}
    parts = score_hard(frame, cv, settings.targets)["parts"]
    assert parts["light_edges"]["located_frames"] == 91
    assert parts["taps"]["located_frames"] == 291
    mixed = mixed_reference({p: parts[p] for p in ("light_edges", "taps")}, cv)
    assert mixed["x_accuracy"] == pytest.approx([(91 * 0.9 + 291 * 0.99) / 382,
                                                 (91 * 0.02 + 291 * 0.005) / 382], abs=1e-4)
    assert mixed["force_mae"] == pytest.approx([(91 * 0.5 + 291 * 0.25) / 382,
                                                (91 * 0.1 + 291 * 0.035) / 382], abs=1e-4)
    assert mixed_reference({"untouched": {"located_frames": 0}}, cv) == cv


def pair_frame(counted: bool) -> pd.DataFrame:
    """A two-contact live hour's frames at 12 ms, each segment 20 frames, the 10th to 20th
    scored (after a press's or a release's 100 ms): untouched, then a pair (1, 10) +
    (10, 1) at 3 and 5 N, then (6, 6) alone at 3 N (a counting plan's presses), each
    placed right from its 10th frame. A counting stack counts a phantom on the last
    untouched frame, none on the pair's 11th frame, and two on the single press's 12th; a
    stack of pairs alone counts nothing and places two on every frame."""
    rows = []
    for i in range(60):
        segment, since = i // 20, 12 * (i % 20)
        pair, single = segment == 1, segment == 2
        placed = segment > 0 and since >= 100
        if counted:
            contacts = (0 if not placed or i == 30 else 2 if pair or i == 51 else 1) \
                if i != 19 else 1
        else:
            contacts = 2
        first = (1.0, 10.0, 3.1) if pair else (6.0, 6.0, 3.1) if single and placed \
            else (1.0, 10.0, 1.0)
        second = (10.0, 1.0, 4.9)
        rows.append({
            "t_ms": 12 * i, "since_ms": since, "pressed": segment > 0, "kind": "press",
            "contact": contacts > 0 if counted else np.nan,
            "contacts": contacts if counted else np.nan,
            **{f"{a}1": v if contacts >= 1 else np.nan
               for a, v in zip(("x", "y", "force"), first, strict=True)},
            **{f"{a}2": v if contacts == 2 else np.nan
               for a, v in zip(("x", "y", "force"), second, strict=True)},
            "true_x1": 1.0 if pair else 6.0 if single else np.nan,
            "true_y1": 10.0 if pair else 6.0 if single else np.nan,
            "true_force1": 3.0 if segment else 0.0,
            "true_x2": 10.0 if pair else np.nan, "true_y2": 1.0 if pair else np.nan,
            "true_force2": 5.0 if pair else np.nan if single else 0.0})
    frame = pd.DataFrame(rows)
    frame.attrs.update(single_frame_seconds=[0.0004], batch_seconds=[0.001])
    return frame


def test_a_counting_two_contact_stack_is_scored_on_phantoms_and_misses_in_the_live_hour():
    from harness.live_hour import render as render_hour
    from harness.live_hour import score_pairs

    counted = score_pairs(pair_frame(counted=True), {"pair_accuracy": [0.91, 0.025]})
    # scored: 11 frames of each segment; a phantom on 1 of 11 untouched; the pair counted
    # none once, the single press two once: 2 of 22 pressed frames counted wrong
    assert counted["counts_contacts"] and counted["untouched_frames"] == 11
    assert (counted["pressed_frames"], counted["pair_frames"]) == (22, 11)
    assert counted["phantom_share"] == pytest.approx(1 / 11, abs=1e-5)
    assert counted["missed_share"] == pytest.approx(1 / 22, abs=1e-5)
    assert counted["count_right_share"] == pytest.approx(20 / 22, abs=1e-5)
    # pairs on the pair's frames only, as the batch pairs are scored
    assert counted["pair_accuracy"] == pytest.approx(10 / 11, abs=1e-5)
    table = render_hour("two_force", {**counted, "script": "a test"})
    assert "| phantom contacts, untouched frames | 9.09 % | ≤ 0.1 % |" in table
    assert "Two contacts, counted" in table and "| | live | target or batch |" in table
    # a stack trained on pairs alone: two on every frame, phantoms and misses not scored
    paired = score_pairs(pair_frame(counted=False).iloc[:40], {})
    assert not paired["counts_contacts"] and paired["phantom_share"] is None
    assert paired["pair_accuracy"] == 1.0
    assert "phantom contacts" not in render_hour("two_force", {**paired, "script": "a test"})


@pytest.mark.parametrize("kind", ["single_force", "two_force"])
def test_the_hours_keep_every_estimate_a_stack_says_but_its_probability(kind):
    # the live hour's frames hold what live said of each frame; a counting stack's count
    # was left out once, and its hour was scored as a stack that counts nothing
    from eskin.kinds import get_kind
    from harness.live_hour import ESTIMATES

    for counted in (False, True):
        said = set(get_kind(kind).stack_outputs(counted=counted)) - {"contact_probability"}
        assert said <= set(ESTIMATES)
