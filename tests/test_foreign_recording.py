"""Another instrument's recording through import (issue 37): a folder of CSVs with a
column map, the labels made from a force/torque sensor, and each wall the issue met."""

from __future__ import annotations

import copy
import re

import numpy as np
import pandas as pd
import pytest
from conftest import acquire_step, eskin, ingest_step, write_params
from foreign_tactile import CHANNELS, GRID_MM, write_recording, write_two_touch_recording

from eskin.config.base import ParamsError, validate_params
from eskin.config.params import Params
from eskin.data.importer import import_paper_layout, rest_offset
from eskin.data.schema import DatasetError, dataset_skin, read_metadata, validate
from eskin.skin import ChannelArray, skin_from_dict

SKIN = {"channels": CHANNELS, "x_mm": list(GRID_MM), "y_mm": list(GRID_MM)}
FROM_NAME = r"x(?P<x_mm>[-\d.]+)_y(?P<y_mm>[-\d.]+)\.csv"
CONTACT_N = 0.5


def magnetic_scene(folder, **changes) -> dict:
    """The scene a lab declares for the recording: every key of the import in play."""
    spec = {"path": str(folder / "*.csv"), "columns": {"force": "Fz", "time": "timestamp"},
            "position_from_name": FROM_NAME, "force_sign": -1, "contact_n": CONTACT_N,
            "trials": "time", "trial_s": 1.4}
    spec.update(changes)
    return {"kind": "single_force", "source": "import", "skin": SKIN,
            "import": {k: v for k, v in spec.items() if v is not None}}


def with_scenes(repo_params, bad_rows="quarantine", **scenes) -> dict:
    params = copy.deepcopy(repo_params)
    params["scenes"] = scenes
    params["ingest"]["bad_rows"] = bad_rows
    return params


def run_import(params, scene, tmp_path):
    acquire_step(params, scene, tmp_path / "raw" / scene)
    result = ingest_step(params, scene, tmp_path / "raw" / scene, tmp_path / "out")
    frame = pd.read_parquet(result.path)
    return result, frame, read_metadata(result.path)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    folder = tmp_path_factory.mktemp("magnetic")
    return write_recording(folder)


@pytest.fixture(scope="module")
def ingested(recording, tmp_path_factory, repo_params):
    tmp = tmp_path_factory.mktemp("ingested")
    params = with_scenes(repo_params, magnetic=magnetic_scene(recording.folder))
    return run_import(params, "magnetic", tmp)


# ---------------------------------------------------------------- the recording, whole

def test_the_folder_gives_a_valid_dataset_on_the_declared_channel_array(ingested, recording):
    result, frame, meta = ingested
    skin = dataset_skin(result.path)
    assert isinstance(skin, ChannelArray) and skin.channels == CHANNELS
    assert skin.x_mm == GRID_MM and skin.size_x == skin.size_y == 3
    validate(frame, "single_force", where=str(result.path), skin=skin)
    source = meta["source"]
    assert source["rows_in_file"] == recording.rows == len(frame) + result.quarantined
    assert source["dropped_frames"] == recording.dropped_frames
    assert source["stale_repeats"] == recording.stale_repeats
    assert result.quarantined == recording.dropped_frames + recording.stale_repeats
    assert (f"{result.quarantined} row(s) quarantined ({recording.dropped_frames} dropped "
            f"frame(s), {recording.stale_repeats} stale repeat(s))") in result.summary
    assert [f["name"] for f in source["files"]] == sorted(p.name for p in recording.files)


def test_each_file_is_its_own_session_in_sorted_order(ingested, recording):
    result, frame, meta = ingested
    files = meta["source"]["files"]
    sessions = frame["session"].drop_duplicates().tolist()
    assert sessions == [f"import-{f['sha256'][:10]}" for f in files]
    per_session = frame.groupby("session", sort=False).size().tolist()
    assert per_session == [f["rows_kept"] for f in files]
    # seq is the data row of its own file: the first rows of every file are at rest, kept
    assert (frame.groupby("session")["seq"].min() == 0).all()
    assert frame["t_ms"].notna().all() and frame["t_ms"].min() == 1_700_000_000_000


def test_each_files_rest_offset_is_removed_and_compression_reads_positive(ingested,
                                                                           recording):
    _, frame, meta = ingested
    for entry in meta["source"]["files"]:
        # the offset as the labels see it: compression positive, so -1 × what Fz read
        assert entry["rest_offset_n"] == pytest.approx(-recording.offsets_n[entry["name"]],
                                                       abs=0.02)
    assert (frame["force"] >= 0).all() and frame["force"].max() > 4


def test_the_contact_rule_finds_the_presses_not_90_percent(ingested, recording):
    result, frame, meta = ingested
    share = meta["source"]["contact_share"]
    assert share == pytest.approx(recording.contact_share(CONTACT_N), abs=0.02)
    assert 0.3 < share < 0.6
    assert f"{share:.0%} contacts (force > 0.5 N over each file's rest offset)" in \
        result.summary
    rest = frame[frame["force"] == 0]
    assert len(rest) and (rest[["x", "y"]] == 0).all().all()
    pressed = frame[frame["force"] > 0]
    assert (pressed["force"] > CONTACT_N).all() and (pressed[["x", "y"]] > 0).all().all()


def test_positions_in_mm_come_from_the_file_names(ingested):
    _, frame, meta = ingested
    pressed = frame[frame["force"] > 0]
    files = {f"import-{f['sha256'][:10]}": f["name"] for f in meta["source"]["files"]}
    for session, rows in pressed.groupby("session"):
        x_mm, y_mm = (float(v) for v in re.findall(r"[-\d.]+(?=_|\.csv)", files[session]))
        assert set(rows["x"]) == {GRID_MM.index(x_mm) + 1}
        assert set(rows["y"]) == {GRID_MM.index(y_mm) + 1}


def test_trials_are_blocks_of_trial_s_seconds(ingested, recording):
    _, frame, _ = ingested
    blocks_per_file = int(np.ceil(4.8 / 1.4))  # 480 rows at 100 Hz
    assert frame["trial"].nunique() == len(recording.files) * blocks_per_file
    span = frame.groupby("trial")["t_ms"].agg(lambda t: t.max() - t.min())
    assert (span < 1400).all()
    assert not frame.duplicated(["session", "trial", "sample"]).any()


# ---------------------------------------------------------------- the walls, one by one

def test_wall_an_import_needs_no_plan_and_refuses_one_in_one_line(repo_params, tmp_path):
    scene = magnetic_scene(tmp_path)
    validate_params(with_scenes(repo_params, magnetic=scene), Params)  # no stretches, no samples
    with pytest.raises(ParamsError) as refused:
        validate_params(with_scenes(repo_params, magnetic={**scene, "stretches": [1.0]}), Params)
    assert str(refused.value) == (
        "params.yaml: scenes.magnetic: an import scene's labels come from its files, not a "
        "plan: remove stretches")
    acquired = copy.deepcopy(repo_params)
    del acquired["scenes"]["single_force"]["stretches"]
    with pytest.raises(ParamsError, match=r"scenes\.single_force\.stretches is missing "
                                          r"\(required\)$"):
        validate_params(acquired, Params)


def test_wall_one_file_per_scene_a_folder_and_a_trial_column(recording, repo_params,
                                                             tmp_path):
    """A folder (not a glob) of files, each with a trial column that runs across files."""
    folder = tmp_path / "lab"
    folder.mkdir()
    for number, path in enumerate(sorted(recording.files)[:3]):
        table = pd.read_csv(path)
        table["run"] = np.where(np.arange(len(table)) < 240, "a", "b")
        table.to_csv(folder / f"{number}_{path.name}", index=False)
    (folder / "README.txt").write_text("not a table")
    scene = magnetic_scene(folder, path=str(folder), trials=None, trial_s=None)
    scene["import"]["columns"]["trial"] = "run"
    _, frame, meta = run_import(with_scenes(repo_params, lab=scene), "lab", tmp_path)
    assert [f["name"] for f in meta["source"]["files"]] == sorted(
        p.name for p in folder.glob("*.csv"))
    assert sorted(t.rsplit("-", 1)[1] for t in frame["trial"].unique()) == ["a", "b"]
    assert frame.groupby("trial").size().sum() == len(frame)
    assert meta["source"]["trials"] == "column"


def test_wall_fixed_widths_an_18_column_file_names_its_columns(repo_params, tmp_path):
    """15 channels and three labels: the paper's layout says what to set; a map reads it."""
    rng = np.random.default_rng(3)
    rows = [[*np.round(rng.normal(0, 30, 15), 3), f, x, y] for f, x, y in
            [(0.0, 0, 0)] * 3 + [(2.0, 1, 2)] * 3 + [(4.0, 3, 3)] * 3 + [(0.0, 0, 0)] * 3]
    path = tmp_path / "flat.csv"
    pd.DataFrame(rows, columns=[*CHANNELS, "load", "px", "py"]).to_csv(path, index=False)
    with pytest.raises(DatasetError, match="18 columns, but the single_force layout has 24 .*"
                                           "name their columns in import.columns"):
        import_paper_layout(path, "single_force")
    scene = {"kind": "single_force", "source": "import",
             "skin": {"channels": CHANNELS, "grid": [3, 3]},
             "import": {"path": str(path),
                        "columns": {"channels": "m*", "force": "load", "x": "px", "y": "py"}}}
    _, frame, _ = run_import(with_scenes(repo_params, "error", flat=scene), "flat", tmp_path)
    assert len(frame) == 12 and frame["trial"].nunique() == 4
    assert frame["x"].tolist() == [0] * 3 + [1] * 3 + [3] * 3 + [0] * 3


def test_wall_padding_a_channel_array_needs_none(tmp_path):
    """The paper's layout on a declared 15-channel skin: 15 channels then the labels."""
    rng = np.random.default_rng(4)
    rows = [[*np.round(rng.normal(0, 30, 15), 3), 2.0, 1 + t % 3, 1, 1.0]
            for t in range(6) for _ in range(2)]
    path = tmp_path / "array.csv"
    pd.DataFrame(rows).to_csv(path, index=False, header=False)
    skin = skin_from_dict({"channels": CHANNELS, "grid": [3, 1]})
    result = import_paper_layout(path, "single_force", skin=skin)
    assert list(result.frame.columns[:15]) == CHANNELS and "cy6" not in result.frame
    assert result.metadata["skin"] == {"channels": CHANNELS, "grid": [3, 1]}


def test_wall_negative_force_says_to_set_the_sign(recording, repo_params, tmp_path):
    scene = magnetic_scene(recording.folder, force_sign=None)
    with pytest.raises(DatasetError, match=r"below the file's rest .* is import\.force_sign "
                                           r"right\?"):
        run_import(with_scenes(repo_params, "error", magnetic=scene), "magnetic", tmp_path)


def test_wall_continuous_force_in_label_runs_says_what_to_set(recording, repo_params,
                                                              tmp_path):
    scene = magnetic_scene(recording.folder, trials=None, trial_s=None)
    with pytest.raises(DatasetError) as refused:
        run_import(with_scenes(repo_params, magnetic=scene), "magnetic", tmp_path)
    message = str(refused.value)
    assert re.search(r"[\d,]+ of [\d,]+ trials are one row long", message), message
    assert "set scenes.<scene>.import.trials: file, or time with trial_s" in message
    assert "\n" not in message


def test_wall_positions_from_names_need_a_contact_rule(repo_params, tmp_path):
    scene = magnetic_scene(tmp_path, contact_n=None)
    with pytest.raises(ParamsError, match="set import.contact_n"):
        validate_params(with_scenes(repo_params, magnetic=scene), Params)


def test_wall_stale_repeats_are_not_fatal_but_a_copy_elsewhere_is(recording, repo_params,
                                                                  tmp_path):
    scene = magnetic_scene(recording.folder)
    result, frame, _ = run_import(with_scenes(repo_params, "error", magnetic=scene),
                                  "magnetic", tmp_path)
    assert result.quarantined == recording.dropped_frames + recording.stale_repeats
    quarantine = pd.read_csv(result.quarantine_path)
    assert set(quarantine["reason"]) == {"dropped frame (every channel 0)",
                                         "stale repeat of the row before (every channel equal)"}
    # A row repeated far from its original is a copy, not a sensor's hiccup: an error.
    folder = tmp_path / "copied"
    folder.mkdir()
    first = sorted(recording.files)[0]
    table = pd.read_csv(first)
    table.loc[300, CHANNELS] = table.loc[100, CHANNELS].to_numpy()
    table.to_csv(folder / first.name, index=False)
    copied = magnetic_scene(folder)
    with pytest.raises(DatasetError, match=rf"{first.name}:302: duplicate of {first.name}:102 "
                                           r"\(every channel equal\)"):
        run_import(with_scenes(repo_params, "error", copied=copied), "copied", tmp_path)


def test_wall_stale_repeats_in_the_papers_layout_are_set_aside_too(tmp_path):
    rng = np.random.default_rng(5)
    rows = [[*np.round(rng.uniform(100, 600, 20), 3), 1.0, 1 + i // 4, 2, 1.0]
            for i in range(12)]
    rows.insert(5, rows[4][:20] + rows[4][20:])   # stale: the row before, again
    rows.insert(9, [0.0] * 20 + rows[9][20:])      # dropped
    path = tmp_path / "paper.csv"
    pd.DataFrame(rows).to_csv(path, index=False, header=False)
    result = import_paper_layout(path, "single_force")  # bad_rows: error
    assert len(result.frame) == 12
    assert [q["reason"] for q in result.quarantine] == [
        "stale repeat of the row before (every channel equal)",
        "dropped frame (every channel 0)"]
    assert result.metadata["source"]["stale_repeats"] == 1
    assert result.metadata["source"]["dropped_frames"] == 1


def test_wall_geometry_keys_are_taken(repo_params):
    params = copy.deepcopy(repo_params)
    params["scenes"]["two_force"].update(skin={"rows": 16, "columns": 12}, nodes_x=[1, 8, 16],
                                         nodes_y=[1, 6, 12])
    params["scenes"]["single_force"]["skin"] = {"channels": CHANNELS, "grid": [3, 3]}
    validate_params(params, Params)


# ---------------------------------------------------------------- labels and their checks

def test_two_touch_files_with_a_total_force_keep_it_and_say_what_they_cannot_give(
        repo_params, tmp_path):
    written = write_two_touch_recording(tmp_path / "two")
    scene = {"kind": "two_force", "source": "import", "skin": SKIN,
             "import": {"path": str(tmp_path / "two"),
                        "columns": {"force": "Fz", "time": "timestamp"},
                        "position_from_name": r"x(?P<x1_mm>[\d.]+)_y(?P<y1_mm>[\d.]+)_"
                                              r"x(?P<x2_mm>[\d.]+)_y(?P<y2_mm>[\d.]+)",
                        "force_sign": -1, "contact_n": CONTACT_N, "trials": "file"}}
    result, frame, meta = run_import(with_scenes(repo_params, two=scene), "two", tmp_path)
    labels = ["force", "x1", "y1", "x2", "y2", "stretch"]
    assert meta["labels"] == labels and list(frame.columns[15:21]) == labels
    assert "force1" not in frame and (frame["force"] > CONTACT_N).all()
    assert "cannot give per-contact forces" in result.summary
    rest = meta["source"]["rows_at_rest"]
    assert rest > 0 and f"{rest} row(s) at rest left out" in result.summary
    assert len(frame) + rest + result.quarantined == written.rows
    first = (frame["x1"] - 1) * 3 + frame["y1"]
    assert (first < (frame["x2"] - 1) * 3 + frame["y2"]).all()  # contact 1 comes first
    assert frame["trial"].nunique() == len(written.files)


def test_positions_in_mm_from_columns_off_the_grid_are_named(repo_params, tmp_path):
    rng = np.random.default_rng(6)
    table = pd.DataFrame(rng.normal(0, 30, (8, 15)), columns=CHANNELS)
    table["F"] = [0.0, 0.1, 3000.0, 2500.0, 0.05, 2000.0, 1500.0, 0.0]  # mN
    table["X"], table["Y"] = [0, 0, 8.3, 8.3, 0, 16, 12, 0], [0, 0, 0, 0, 0, 7.8, 8, 0]
    path = tmp_path / "mm.csv"
    table.to_csv(path, index=False)
    scene = {"kind": "single_force", "source": "import", "skin": SKIN,
             "import": {"path": str(path),
                        "columns": {"force": "F", "x_mm": "X", "y_mm": "Y"},
                        "force_unit": "mN", "contact_n": 0.5, "trials": "file"}}
    params = with_scenes(repo_params, "error", mm=scene)
    with pytest.raises(DatasetError, match=r"mm.csv:8: x_mm = 12 is off the skin's grid "
                                           r"\(skin.x_mm; tolerance 2 mm\)"):
        run_import(params, "mm", tmp_path)
    params["ingest"]["bad_rows"] = "quarantine"
    _, frame, _ = run_import(params, "mm", tmp_path)
    assert frame["force"].tolist() == pytest.approx([0, 0, 3.0, 2.5, 0, 2.0, 0], abs=1e-3)
    assert frame["x"].tolist() == [0, 0, 2, 2, 0, 3, 0]
    assert frame["y"].tolist() == [0, 0, 1, 1, 0, 2, 0]


def test_a_file_name_off_the_pattern_or_the_grid_stops_before_acquisition(
        recording, repo_params, tmp_path):
    folder = tmp_path / "names"
    folder.mkdir()
    source = sorted(recording.files)[0].read_bytes()
    (folder / "press_x5_y0.csv").write_bytes(source)
    params = with_scenes(repo_params, names=magnetic_scene(folder))
    write_params(tmp_path, params)
    result = eskin(["acquire", "names", "--no-progress"], tmp_path)
    assert result.returncode == 1 and result.stderr.count("\n") == 1, result.stderr
    assert result.stderr.strip() == (
        f"eskin: error: scenes.names.import: {folder}/press_x5_y0.csv: its name places x at "
        "5 mm, off the skin's grid (skin.x_mm: 0, 8, 16; tolerance 2 mm)")
    (folder / "press_x5_y0.csv").rename(folder / "press_centre.csv")
    result = eskin(["acquire", "names", "--no-progress"], tmp_path)
    assert "press_centre.csv: the file's name does not match import.position_from_name" in \
        result.stderr and result.stderr.count("\n") == 1


def test_a_column_the_header_lacks_is_one_line_with_the_closest(recording, repo_params,
                                                                tmp_path):
    scene = magnetic_scene(recording.folder)
    scene["import"]["columns"]["force"] = "fz"
    params = with_scenes(repo_params, magnetic=scene)
    write_params(tmp_path, params)
    result = eskin(["acquire", "magnetic", "--no-progress"], tmp_path)
    assert result.returncode == 1 and result.stderr.count("\n") == 1, result.stderr
    assert "no column 'fz' (import.columns.force); did you mean 'Fz'?" in result.stderr


@pytest.mark.parametrize("changes, message", [
    ({"columns": {"force": "Fz", "force1": "Fz", "time": "timestamp"}},
     "columns.force1 is not a label of a single_force scene"),
    ({"columns": {"time": "timestamp"}}, "import.columns needs force"),
    ({"trials": "time", "trial_s": None}, "trials: time cuts the rows into blocks of trial_s"),
    ({"columns": {"force": "Fz", "trial": "run", "time": "timestamp"}},
     "columns.trial and trials: time both say where trials are; keep one"),
    ({"position_from_name": r"x(?P<col>\d)"}, "position_from_name names groups ['col']"),
    ({"columns": {"force": "Fz", "channels": ["m1x"], "time": "timestamp"}},
     "channels lists 1 columns but the skin has 15 channels"),
    ({"force_sign": 2}, "force_sign = 2: Input should be 1 or -1"),
    ({"force_unt": "mN"}, "import.force_unt is not a known key; did you mean "
                          "scenes.magnetic.import.force_unit?"),
])
def test_an_import_section_mistake_is_one_line(repo_params, tmp_path, changes, message):
    scene = magnetic_scene(tmp_path, **changes)
    with pytest.raises(ParamsError) as refused:
        validate_params(with_scenes(repo_params, magnetic=scene), Params)
    assert message in str(refused.value) and "\n" not in str(refused.value), refused.value


def test_the_rest_offset_ignores_presses_and_noise():
    rng = np.random.default_rng(9)
    rest = 0.37 + rng.normal(0, 0.02, 300)
    presses = rng.uniform(1, 5, 500)  # most of the file pressed
    assert rest_offset(np.r_[rest, presses + 0.37], 0.5) == pytest.approx(0.37, abs=0.005)
    assert rest_offset(rest, 0.5) == pytest.approx(0.37, abs=0.005)
