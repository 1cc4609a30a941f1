"""Any skin, the whole pipeline (issue 37): `dvc repro` in a scratch project whose scenes
are a simulated 8 × 8 row/column skin (one contact), acquired over the pty from the
firmware built for 8 × 8 under simavr, a simulated 16 × 12 one (two contacts), acquired
over the pty from the Python board, and a magnetic skin's recording (a channel array of
15 magnetometer channels, one CSV per press position, F/T force negative in compression
with an offset, dropped and stale frames) imported through a column map.

The magnetic scene's force model is scored against a plain scikit-learn baseline on the
same folds (the out-of-fold predictions' own fold column): the two must agree within the
spread of their fold scores. (The paper's own skin is the main project's: its dvc.lock.)
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import onnx
import pandas as pd
import pyarrow.parquet as pq
import pytest
from conftest import quick_params, run_checked, scratch_project
from foreign_tactile import CHANNELS, GRID_MM, write_recording
from sklearn.ensemble import HistGradientBoostingRegressor
from sklearn.metrics import r2_score

# Each test here starts a pipeline or a server: `make check` leaves them out.
pytestmark = pytest.mark.starts

FROM_NAME = r"x(?P<x_mm>[-\d.]+)_y(?P<y_mm>[-\d.]+)\.csv"


def scenes(recording: Path) -> dict:
    return {
        "lab8": {"kind": "single_force", "source": "emulated",
                 "skin": {"rows": 8, "columns": 8}, "stretches": [1.0, 1.07921],
                 "forces": [0.0, 3.2536], "samples": 5},
        "lab16x12": {"kind": "two_force", "source": "simulated",
                     "skin": {"rows": 16, "columns": 12}, "stretches": [1.0],
                     "forces": [1.2936, 5.2136], "nodes_x": [1, 8, 16],
                     "nodes_y": [1, 6, 12], "samples": 5},
        "magnetic": {"kind": "single_force", "source": "import",
                     "skin": {"channels": CHANNELS, "x_mm": list(GRID_MM),
                              "y_mm": list(GRID_MM)},
                     "import": {"path": str(recording / "*.csv"),
                                "columns": {"force": "Fz", "time": "timestamp"},
                                "position_from_name": FROM_NAME, "force_sign": -1,
                                "contact_n": 0.5, "trials": "time", "trial_s": 1.4}},
    }


@pytest.fixture(scope="module")
def project(tmp_path_factory, repo_params):
    base = tmp_path_factory.mktemp("skins")
    recording = write_recording(base / "magnetic")
    params = copy.deepcopy(repo_params)
    params["scenes"] = scenes(recording.folder)
    params["ingest"]["bad_rows"] = "quarantine"  # the recording's dropped and stale frames
    # Conditions CV only, few folds: the skins, not the paper's scheme, are under test.
    quick_params(params, folds=5, conditions_only=True)
    root = base / "project"
    root.mkdir()
    env = scratch_project(root, params, f"sqlite:///{base / 'mlflow.db'}")
    run_checked(["dvc", "repro"], root, env)
    return root, env, recording


def scores(root: Path, scene: str, task: str) -> dict:
    return json.loads((root / "reports/scores" / scene / f"{task}.json").read_text())


@pytest.mark.parametrize("scene, rows, columns", [("lab8", 8, 8), ("lab16x12", 16, 12)])
def test_a_simulated_row_column_skin_of_its_size_goes_through_every_stage(project, scene,
                                                                           rows, columns):
    root, *_ = project
    frame = pd.read_parquet(root / "data/processed" / f"{scene}.parquet")
    channels = [f"cx{i}" for i in range(1, rows + 1)] + [f"cy{i}" for i in range(1, columns + 1)]
    assert [c for c in frame.columns if c.startswith("c")] == channels
    device = json.loads(pq.read_schema(root / "data/processed" / f"{scene}.parquet")
                        .metadata[b"eskin.device"])
    assert device["terminals"] == rows + columns
    localise = scores(root, scene, "localise")
    if scene == "lab8":  # the firmware, built for 8 × 8, names its size
        assert device["firmware"].endswith("+8x8"), device
        assert localise["source"].startswith(f"emulated firmware {device['firmware']} "
                                             "under simavr (seed ")
    assert localise["status"] == "trained"
    targets = ("x", "y") if scene == "lab8" else ("x1", "y1", "x2", "y2")
    for target in targets:  # far above chance (1 in 8 to 1 in 16 terminals)
        assert localise["conditions"][target]["accuracy"] > 0.5, (target, localise["conditions"])
    stack = onnx.load(root / "models" / scene / "stack.onnx")
    width = stack.graph.input[0].type.tensor_type.shape.dim[1].dim_value
    assert width == rows + columns


def test_the_one_contact_skin_weighs_and_detects(project):
    root, *_ = project
    assert scores(root, "lab8", "stretch")["conditions"]["stretch"]["r2"] > 0.9
    assert scores(root, "lab8", "force")["conditions"]["force"]["r2"] > 0.5
    assert scores(root, "lab8", "detect")["conditions"]["contact"]["accuracy"] > 0.9


def test_the_magnetic_recording_is_read_as_written(project):
    root, _, recording = project
    frame = pd.read_parquet(root / "data/processed/magnetic.parquet")
    assert list(frame.columns[:15]) == CHANNELS
    quarantine = pd.read_csv(root / "data/processed/magnetic.quarantine.csv")
    assert len(quarantine) == recording.dropped_frames + recording.stale_repeats
    assert len(frame) == recording.rows - len(quarantine)


def test_the_magnetic_skin_gets_generic_models_and_its_error_in_mm(project):
    root, *_ = project
    force = scores(root, "magnetic", "force")
    assert force["status"] == "trained" and force["model"] != "physics_profile"
    localise = scores(root, "magnetic", "localise")["conditions"]
    # within one 8 mm pitch on average, and accurate far above chance (1 in 3)
    assert localise["position"]["error_mm"] < 8.0, localise["position"]
    assert localise["x"]["accuracy"] > 0.6 and localise["y"]["accuracy"] > 0.6
    assert "one stretch level" in scores(root, "magnetic", "stretch")["reason"] or \
        scores(root, "magnetic", "stretch")["status"] == "skipped"
    page = (root / "reports/index.html").read_text()
    assert 'id="scene-magnetic"' in page and "array of 15 channels" in page


def test_the_magnetic_force_agrees_with_a_plain_baseline_on_the_same_folds(project):
    root, *_ = project
    data = pd.read_parquet(root / "data/processed/magnetic.parquet")
    predictions = pd.read_parquet(root / "reports/predictions/magnetic/force.parquet")
    predictions = predictions[predictions["scheme"] == "conditions"]
    keys = ["session", "trial", "sample"]
    rows = data.reset_index().merge(predictions[keys + ["fold"]], on=keys)
    ours, plain = [], []
    for fold in sorted(rows["fold"].unique()):
        held = rows["fold"] == fold
        truth = rows.loc[held, "force"]
        model = HistGradientBoostingRegressor(random_state=0)
        model.fit(rows.loc[~held, CHANNELS], rows.loc[~held, "force"])
        plain.append(r2_score(truth, model.predict(rows.loc[held, CHANNELS])))
        mine = predictions[predictions["fold"] == fold]
        ours.append(r2_score(mine["force_true"], mine["force_pred"]))
    spread = max(np.std(ours), np.std(plain))
    assert abs(np.mean(ours) - np.mean(plain)) <= spread, (ours, plain)
    reported = scores(root, "magnetic", "force")["conditions"]["force"]["r2"]
    assert reported == pytest.approx(np.mean(ours), abs=1e-9)
