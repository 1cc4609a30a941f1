"""Importing external data in the paper's layout, and every bad file we could think of."""

import copy

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from conftest import acquire_step, ingest_step

from eskin.data.importer import import_paper_layout
from eskin.data.schema import DatasetError, arrow_schema, read_metadata
from eskin.skin import PAPER_SKIN

rng = np.random.default_rng(0)


def paper_rows(n_trials=6, samples=4, kind="single_force"):
    rows = []
    for t in range(n_trials):
        caps = rng.uniform(100, 600, size=20)
        labels = ([1.2936 * (t % 3), t % 11, (t * 3) % 11, 1.0 + 0.07921 * (t % 2)]
                  if kind == "single_force" else [1.2936, 1, 1, 3.2536, 6, 10])
        for _ in range(samples):
            rows.append([*np.round(caps + rng.normal(0, 1, 20), 3), *labels])
    return rows


def write_csv(path, rows, header=None):
    lines = ([",".join(header)] if header else []) + [",".join(map(str, r)) for r in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_csv_in_the_paper_layout_gets_the_dataset_schema(tmp_path):
    result = import_paper_layout(write_csv(tmp_path / "skin.csv", paper_rows()), "single_force")
    frame = result.frame
    assert len(frame) == 24 and result.quarantine == []
    table = pa.Table.from_pandas(frame, schema=arrow_schema("single_force"), preserve_index=False)
    assert table.num_rows == 24
    assert frame["trial"].nunique() == 6 and frame["sample"].max() == 3
    assert frame["t_ms"].isna().all() and frame["seq"].tolist() == list(range(24))
    assert result.metadata["source"]["sha256"]


def test_header_row_and_two_force_layout_without_stretch(tmp_path):
    header = PAPER_SKIN.channels + ["force1", "x1", "y1", "force2", "x2", "y2"]
    path = write_csv(tmp_path / "two.csv", paper_rows(kind="two_force"), header)
    result = import_paper_layout(path, "two_force")
    assert len(result.frame) == 24 and (result.frame["stretch"] == 1.0).all()
    assert result.metadata["source"]["stretch_assumed"] is True


def test_parquet_import_matches_csv_import(tmp_path):
    rows = paper_rows()
    csv = import_paper_layout(write_csv(tmp_path / "a.csv", rows), "single_force").frame
    pd.DataFrame(rows).set_axis([f"c{i}" for i in range(24)], axis=1).to_parquet(
        tmp_path / "a.parquet")
    parquet = import_paper_layout(tmp_path / "a.parquet", "single_force").frame
    pd.testing.assert_frame_equal(csv.drop(columns=["session", "trial"]),
                                  parquet.drop(columns=["session", "trial"]))


@pytest.mark.parametrize("damage, message", [
    (lambda r: r[5].__setitem__(3, "nan"), r"bad.csv:6: cx4 is NaN or empty"),
    (lambda r: r[2].__setitem__(21, 11), r"bad.csv:3: x is not a node number 0..10"),
    (lambda r: r[7].__setitem__(0, "12,5"), r"bad.csv:8: row has 25 columns, expected 24"),
    (lambda r: r[1].__setitem__(4, "abc"), r"bad.csv:2: cx5 is not a number"),
    (lambda r: r[9].__setitem__(10, "inf"), r"bad.csv:10: cy1 is infinite"),
    (lambda r: r[4].__setitem__(20, -1.0), r"bad.csv:5: force is negative"),
    (lambda r: r[4].__setitem__(22, 2.5), r"bad.csv:5: y is not a node number"),
])
def test_bad_rows_are_errors_naming_file_line_and_problem(tmp_path, damage, message):
    rows = [list(r) for r in paper_rows()]
    damage(rows)
    path = write_csv(tmp_path / "bad.csv", rows)
    with pytest.raises(DatasetError, match=message):
        import_paper_layout(path, "single_force")
    quarantined = import_paper_layout(path, "single_force", bad_rows="quarantine")
    assert len(quarantined.frame) == 23 and len(quarantined.quarantine) == 1
    assert quarantined.metadata["source"]["rows_quarantined"] == 1


@pytest.mark.parametrize("content, message", [
    (b"", "empty"),
    (b"\n\n", "no data rows"),
    (b"a,b,c\n", "no data rows"),
    (b"1,2,3\n", "3 columns, but the single_force layout has 24"),
    (b"\xff\xfe1,2\n", "not UTF-8"),
    (b"1,2\x00,3\n", "NUL"),
])
def test_bad_files_are_errors_naming_the_file(tmp_path, content, message):
    path = tmp_path / "broken.csv"
    path.write_bytes(content)
    with pytest.raises(DatasetError, match=message) as info:
        import_paper_layout(path, "single_force")
    assert "broken.csv" in str(info.value)


def test_two_force_file_given_as_single_force_says_which_layout_it_is(tmp_path):
    path = write_csv(tmp_path / "two.csv", paper_rows(kind="two_force"))
    with pytest.raises(DatasetError, match="26 columns.*that is the two_force layout"):
        import_paper_layout(path, "single_force")


def test_truncated_parquet_is_a_clear_error(tmp_path):
    pd.DataFrame(paper_rows()).set_axis([f"c{i}" for i in range(24)], axis=1).to_parquet(
        tmp_path / "full.parquet")
    data = (tmp_path / "full.parquet").read_bytes()
    (tmp_path / "cut.parquet").write_bytes(data[: len(data) // 2])
    with pytest.raises(DatasetError, match="cut.parquet: not a readable Parquet"):
        import_paper_layout(tmp_path / "cut.parquet", "single_force")


def test_import_source_runs_through_the_pipeline_steps(tmp_path, small_params):
    source = write_csv(tmp_path / "lab.csv", paper_rows())
    params = copy.deepcopy(small_params)
    params["scenes"]["single_force"] = {"kind": "single_force", "source": "import",
                                        "import": {"path": str(source)}}
    acquire_step(params, "single_force", tmp_path / "raw")
    assert (tmp_path / "raw" / "import" / "lab.csv").read_bytes() == source.read_bytes()
    message = ingest_step(params, "single_force", tmp_path / "raw", tmp_path / "out").summary
    assert "24 rows" in message
    frame = pq.read_table(tmp_path / "out" / "single_force.parquet").to_pandas()
    assert len(frame) == 24
    assert read_metadata(tmp_path / "out" / "single_force.parquet")["source"]["kind"] == "import"


def test_streaming_in_small_chunks_gives_the_same_dataset_and_quarantine(tmp_path,
                                                                         monkeypatch):
    """Chunk boundaries change nothing: trials run across them, copies are found across
    them, and a bad row is named by its line wherever it falls."""
    from eskin.data import importer

    rows = paper_rows()
    rows = rows + [rows[3]] + rows[:2]  # copies of earlier rows, in a later chunk
    rows[5] = rows[5][:4] + ["oops"] + rows[5][5:]
    path = write_csv(tmp_path / "skin.csv", rows)
    whole = import_paper_layout(path, "single_force", bad_rows="quarantine")
    monkeypatch.setattr(importer, "CHUNK_ROWS", 3)
    chunked = import_paper_layout(path, "single_force", bad_rows="quarantine")
    pd.testing.assert_frame_equal(whole.frame, chunked.frame)
    assert whole.quarantine == chunked.quarantine
    reasons = [q["reason"] for q in chunked.quarantine]
    assert sum(r.startswith("duplicate of line") for r in reasons) == 3
    assert any("is not a number" in r for r in reasons)


LAB_HEADERS = {
    # The paper's own names: the terminals are x1..x10 and y1..y10.
    "paper": [f"x{i}" for i in range(1, 11)] + [f"y{i}" for i in range(1, 11)]
    + ["force", "x", "y", "stretch"],
    "numbered channels, units": [f"C{i}" for i in range(1, 21)]
    + ["Force (N)", "node_x", "node_y", "λ"],
    "upper case, spaces": [f"CX {i}" for i in range(1, 11)] + [f"CY {i}" for i in range(1, 11)]
    + ["FORCE", "X", "Y", "Stretch"],
}


@pytest.mark.parametrize("naming", sorted(LAB_HEADERS))
def test_a_lab_header_in_its_own_names_is_recognised(tmp_path, naming):
    path = write_csv(tmp_path / "lab.csv", paper_rows(), LAB_HEADERS[naming])
    result = import_paper_layout(path, "single_force")
    assert len(result.frame) == 24 and result.frame["stretch"].nunique() == 2


def test_a_two_force_header_in_the_papers_names_is_recognised(tmp_path):
    header = ([f"x{i}" for i in range(1, 11)] + [f"y{i}" for i in range(1, 11)]
              + ["F1", "x1", "y1", "F2", "x2", "y2"])
    result = import_paper_layout(write_csv(tmp_path / "two.csv", paper_rows(kind="two_force"),
                                           header), "two_force")
    assert len(result.frame) == 24 and (result.frame["x2"] == 6).all()


def test_a_header_naming_a_column_elsewhere_says_what_to_rename(tmp_path):
    header = LAB_HEADERS["paper"][:20] + ["x", "y", "force", "stretch"]
    path = write_csv(tmp_path / "swapped.csv", paper_rows(), header)
    with pytest.raises(DatasetError) as refused:
        import_paper_layout(path, "single_force")
    message = str(refused.value)
    assert message.startswith(f"{path}:1: the header has 'x' in column 21, where the layout "
                              "has 'force'") and "rename it" in message, message
    assert "\n" not in message


BAD_SCENES = {
    "missing file": (lambda d: {"import": {"path": str(d / "nowhere.csv")}},
                     "scenes.lab.import.path = '{d}/nowhere.csv': no such file"),
    "other kind's layout": (lambda d: {"import": {"path": str(write_csv(
        d / "two.csv", paper_rows(kind="two_force")))}},
        "scenes.lab.import: {d}/two.csv: 26 columns, but the single_force layout has 24 "
        "— that is the two_force layout (the skin's 20 channels, then force, x, y, "
        "stretch); for another instrument's files, name their columns in import.columns"),
    "too few conditions": (lambda d: {"kind": "two_force", "source": "simulated",
                                  "stretches": [1.0], "forces": [1.0], "nodes_x": [1, 6],
                                  "nodes_y": [1], "samples": 4},
                       "scenes.lab: 1 condition(s), but conditions CV with cv.folds = 10 "
                       "needs at least 10; add stretches, forces or nodes, or lower cv.folds"),
}


@pytest.mark.parametrize("mistake", sorted(BAD_SCENES))
def test_a_bad_scene_stops_every_acquisition_before_it_starts(tmp_path, repo_params, mistake):
    """One line naming the scene and the key, before the first scene is acquired; nothing
    of the good scene is recorded."""
    from conftest import eskin, write_params

    make, expected = BAD_SCENES[mistake]
    params = copy.deepcopy(repo_params)
    params["scenes"]["lab"] = {"kind": "single_force", "source": "import", **make(tmp_path)}
    write_params(tmp_path, params)
    result = eskin(["acquire", "single_force", "--no-progress"], tmp_path)
    assert result.returncode == 1 and result.stderr.count("\n") == 1, result.stderr
    assert result.stderr.strip() == f"eskin: error: {expected.format(d=tmp_path)}"
    assert not (tmp_path / "data").exists()
