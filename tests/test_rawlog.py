"""The raw log: torn tails after a crash, damaged lines on disk, the CLI's errors."""

import copy

import pytest
from conftest import acquire_step, eskin, ingest_step, write_params

from eskin.data.rawlog import RawLogError, RawLogWriter, read_log
from eskin.data.schema import DatasetError
from eskin.device.protocol import encode_frame, parse_line

FRAME = parse_line(encode_frame(0, 0, [500] * 20)[:-1])
DEVICE = {"id": "d", "firmware": "f", "terminals": 20}  # frames are read at its width


def write_one_condition(path, key="k1"):
    writer = RawLogWriter(path, {"session": "s001", "device": DEVICE})
    attempt = writer.begin({"key": key, "stretch": 1.0, "contacts": [[0, 0, 0.0]]})
    writer.frames(attempt, [FRAME])
    writer.end(attempt, 1)
    writer.close()


def test_torn_last_line_is_ignored_and_cut_on_reopen(tmp_path):
    path = tmp_path / "acquisition.log"
    write_one_condition(path)
    with path.open("ab") as handle:
        handle.write(b"B\t2\t{\"key\": \"k2\", \"stre")  # killed mid-write
    contents = read_log(path)
    assert contents.torn_tail and set(contents.completed) == {"k1"} and not contents.bad_lines
    RawLogWriter(path, {"session": "s002", "device": DEVICE}).close()
    assert path.read_bytes().endswith(b"\n") and b'"k2"' not in path.read_bytes()
    assert set(read_log(path).completed) == {"k1"}


def test_not_a_raw_log_is_rejected_at_line_one(tmp_path):
    path = tmp_path / "acquisition.log"
    path.write_text("hello\n")
    with pytest.raises(RawLogError, match="acquisition.log:1: not an eskin raw log"):
        read_log(path)


def test_frame_damaged_on_disk_is_named_and_its_condition_not_trusted(tmp_path):
    path = tmp_path / "acquisition.log"
    write_one_condition(path)
    text = path.read_text().replace("D,0,0,500,", "D,0,0,501,")
    path.write_text(text)
    contents = read_log(path)
    assert contents.completed == {}
    assert "acquisition.log:4: stored frame does not verify: CRC mismatch" in str(
        contents.bad_lines[0])


def test_damaged_log_stops_ingest_or_goes_to_quarantine(tmp_path, small_params):
    acquire_step(small_params, "single_force", tmp_path, progress=False)
    log = tmp_path / "acquisition.log"
    lines = log.read_text().splitlines(keepends=True)
    frame_line = next(i for i, line in enumerate(lines) if line.startswith("F\t"))
    lines[frame_line] = lines[frame_line].replace(",", ";", 3)
    log.write_text("".join(lines))
    with pytest.raises(DatasetError, match=f"acquisition.log:{frame_line + 1}: .*quarantine"):
        ingest_step(small_params, "single_force", tmp_path, tmp_path / "out")
    lenient = copy.deepcopy(small_params)
    lenient["ingest"]["bad_rows"] = "quarantine"
    with pytest.raises(DatasetError, match="1 of 404 planned conditions"):
        ingest_step(lenient, "single_force", tmp_path, tmp_path / "out")
    summary = acquire_step(lenient, "single_force", tmp_path, progress=False).summary
    assert "1 trial(s) acquired, 403 reused" in summary
    message = ingest_step(lenient, "single_force", tmp_path, tmp_path / "out").summary
    assert "2020 rows" in message and "1 row(s) quarantined" in message
    assert "does not verify" in (tmp_path / "out" / "single_force.quarantine.csv").read_text()


def test_cli_turns_errors_into_one_line_and_exit_one(tmp_path, small_params):
    write_params(tmp_path, small_params)
    result = eskin(["ingest", "single_force"], tmp_path)
    assert result.returncode == 1
    assert result.stderr.strip().startswith("eskin: error: ")
    assert "eskin acquire single_force" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    unknown = eskin(["acquire", "no_such_scene"], tmp_path)
    assert unknown.returncode == 1 and "no scene 'no_such_scene'" in unknown.stderr
    assert "single_force, two_force" in unknown.stderr  # the scenes that exist


def test_a_reason_that_is_not_ascii_is_written_escaped_not_lost(tmp_path):
    path = tmp_path / "acquisition.log"
    writer = RawLogWriter(path, {"session": "s001", "device": DEVICE})
    attempt = writer.begin({"key": "k1", "stretch": 1.0, "contacts": [[0, 0, 0.0]]})
    writer.abandon(attempt, "limit 40 or 10 σ\ton /dev/ttyÄCM0")
    writer.close()
    assert path.read_text(encoding="ascii").splitlines()[-1] == \
        "X\t1\tlimit 40 or 10 \\u03c3 on /dev/tty\\xc4CM0"
    assert not read_log(path).bad_lines
