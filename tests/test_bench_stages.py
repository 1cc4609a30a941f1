"""The bench's live and harder hour stages (stages/live_hour.py, stages/hard_hour.py), from
script to report, on a stand-in for the live stack that is always right and reads a frame
every 200 ms. What this checks is the glue between a stage, its harness, the scene's kind and
the scorers, which `make test` otherwise never runs: a Kind property renamed in 23f6606
left `dvc repro live_hour@single_force` failing unseen until 98ef704. The real stack on
the real board is the bench's (and tests/test_live_ghosts.py's); a fresh clone has no
workspace models to run it on here."""

from __future__ import annotations

import json

import pandas as pd
import pytest

import stages.hard_hour
import stages.live_hour
from eskin.config.base import load_params
from eskin.config.params import Params
from eskin.config.scenes import get_scene
from eskin.data.plan import plan_from_params
from harness.live_hour import script

PERIOD_MS = 200  # a frame every 200 ms (a tap has one scored): the glue is under test


def always_right(scene: str, settings, params_path=None, *, steps_of=None,
                 stack_kind: str = "onnx") -> pd.DataFrame:
    """What harness.live_hour.run returns, from a stack that reports the script's truth
    (a two-contact stack that counts none places a pair on untouched frames too, as the
    paper plan's does)."""
    params = load_params(Params)
    plan = plan_from_params(scene, get_scene(params, scene))
    rest_mm = float(params.acquire.rest_length_mm)
    if steps_of is None:
        steps, end_ms = script(settings, plan, rest_mm), int(settings.minutes * 60_000)
    else:
        steps, end_ms = steps_of(plan, rest_mm)
    several = len(plan.conditions[0].contacts) > 1
    rows = []
    for step, after in zip(steps, [*steps[1:], None], strict=True):
        for t_ms in range(step.at_ms, end_ms if after is None else after.at_ms, PERIOD_MS):
            row = {"t_ms": t_ms, "kind": step.kind, "part": step.part,
                   "since_ms": t_ms - step.at_ms, "pressed": bool(step.press),
                   "true_stretch": 1 + step.stretch_mm / rest_mm,
                   "stretch": 1 + step.stretch_mm / rest_mm}
            if several:
                placed = step.press or ((1, 1, 0.0), (10, 10, 0.0))
                for i, (x, y, newtons) in enumerate(placed, 1):
                    truth = step.press[i - 1] if step.press else (None, None, 0.0)
                    row.update({f"true_x{i}": truth[0], f"true_y{i}": truth[1],
                                f"true_force{i}": truth[2], f"x{i}": x, f"y{i}": y,
                                f"force{i}": newtons})
                row["contact"] = None
            else:
                (x, y, newtons), = step.press or ((None, None, 0.0),)
                row.update({"true_x": x, "true_y": y, "true_force": newtons,
                            "contact": bool(step.press), "x": x, "y": y, "force": newtons})
            rows.append(row)
    frame = pd.DataFrame(rows)
    frame.attrs.update(batch_seconds=[0.001], single_frame_seconds=[0.0003], steps=len(steps),
                       frame_period_ms=PERIOD_MS,
                       stretches_mm=[s.stretch_mm for s in steps if s.kind == "stretch"])
    return frame


@pytest.fixture
def reports(tmp_path, monkeypatch):
    for stage in (stages.live_hour, stages.hard_hour):
        monkeypatch.setattr(stage, "run", always_right)
        monkeypatch.setattr(stage, "REPORT", tmp_path / stage.__name__.rpartition(".")[2])
    return tmp_path


@pytest.mark.parametrize("scene", ["single_force", "two_force"])
def test_the_live_hour_stage_scores_a_stack_that_is_always_right(reports, scene):
    assert stages.live_hour.main(scene) == 0
    result = json.loads((reports / "live_hour" / f"{scene}.json").read_text())
    assert (reports / "live_hour" / f"{scene}.md").read_text().startswith("# Live hour")
    if scene == "single_force":
        assert result["phantom_share"] == 0 and result["missed_share"] == 0
        assert result["location_accuracy"] == 1 and result["force_mae_n"] == 0
        assert result["sustained_detected_at_end"] is True
    else:
        assert result["pair_accuracy"] == 1 and result["force_mae_n"] == 0
    assert result["hours"] == pytest.approx(1.0, abs=0.01)


@pytest.mark.parametrize("scene", ["single_force", "two_force"])
def test_the_harder_hour_stage_scores_a_stack_that_is_always_right(reports, scene):
    assert stages.hard_hour.main(scene) == 0
    result = json.loads((reports / "hard_hour" / f"{scene}.json").read_text())
    table = (reports / "hard_hour" / f"{scene}.md").read_text()
    whole = result["parts"]["whole"]
    assert whole["missed_share"] == 0 and whole["force_mae_n"] == 0
    assert whole["held_share"] == 1
    if scene == "single_force":
        assert all(part["met"] for part in result["parts"].values()), table
        assert "MISSED" not in table
    else:
        # a stack that counts no contact reports two on every untouched frame: the known
        # miss, said under the table
        assert result["two_contacts"] and not result["counts_contacts"]
        assert whole["phantom_share"] == 1 and whole["pair_accuracy"] == 1
        assert "so every untouched frame is a phantom" in table
    assert whole["presses_never_seen"] == 0 and result["hours"] > 2
