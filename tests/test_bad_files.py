"""Every malformed import and raw log we could think of: a clear error naming the file
(and the line, where there is one), quarantine where rows are salvageable, nothing
dropped silently. `python tests/test_bad_files.py` prints what each case produces."""

import json
import re
import sys
from pathlib import Path

import pandas as pd
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from eskin.data.importer import import_paper_layout  # noqa: E402
from eskin.data.plan import single_force_plan  # noqa: E402
from eskin.data.rawlog import RawLogError, RawLogWriter  # noqa: E402
from eskin.data.schema import DatasetError  # noqa: E402
from eskin.device.protocol import encode_frame, parse_line  # noqa: E402
from eskin.steps.ingest import ingest_log  # noqa: E402

# ---------------------------------------------------------------- imports

def paper_csv(rows: int = 12) -> list[str]:
    """Single-force rows in the paper's layout: 3 trials of 4 noisy samples."""
    lines = []
    for i in range(rows):
        channels = [str(500 + (7 * i + 3 * j) % 11) for j in range(20)]
        lines.append(",".join(channels + ["1.2936", str(1 + i // 4), "2", "1.0"]))
    return lines


def edit(index: int, column: int, value: str):
    def damage(lines):
        cells = lines[index].split(",")
        cells[column] = value
        lines[index] = ",".join(cells)
        return lines
    return damage


IMPORT_CASES = {
    # name: (file bytes, policy → expected: ("error", regex) or ("quarantined", n))
    "wrong header order": ((",".join([f"cx{i}" for i in range(1, 11)] + [
        f"cy{i}" for i in range(1, 11)] + ["x", "force", "y", "stretch"]) + "\n"
        + "\n".join(paper_csv())).encode(), ("error", r":1: the header has 'x' in column 21")),
    "wrong column count": (b"1,2,3\n4,5,6\n", ("error", r"3 columns, but the single_force "
                                                        r"layout has 24")),
    "two-force file as single force": (("\n".join(",".join(["5"] * 26) for _ in range(3)))
                                       .encode(), ("error", r"that is the two_force layout")),
    "text in a numeric column": ("\n".join(edit(4, 7, "abc")(paper_csv())).encode(),
                                 ("quarantined", 1, r":5: cx8 is not a number")),
    "NaN": ("\n".join(edit(2, 3, "nan")(paper_csv())).encode(),
            ("quarantined", 1, r":3: cx4 is NaN or empty")),
    "inf": ("\n".join(edit(6, 20, "inf")(paper_csv())).encode(),
            ("quarantined", 1, r":7: force is infinite")),
    "empty cell": ("\n".join(edit(1, 0, "")(paper_csv())).encode(),
                   ("quarantined", 1, r":2: cx1 is NaN or empty")),
    "node out of range": ("\n".join(edit(3, 21, "11")(paper_csv())).encode(),
                          ("quarantined", 1, r":4: x is not a node number")),
    "duplicate rows": ("\n".join(paper_csv() + paper_csv()[2:4]).encode(),
                       ("quarantined", 2, r":13: duplicate of line 3")),
    "mixed scenes": ("\n".join(paper_csv() + [",".join(["5"] * 26)]).encode(),
                     ("quarantined", 1, r":13: row has 26 columns, expected 24 \(a two_force")),
    "short row": ("\n".join(paper_csv()[:5] + ["1,2,3"] + paper_csv()[5:]).encode(),
                  ("quarantined", 1, r":6: row has 3 columns, expected 24")),
    "empty file": (b"", ("error", r": file is empty")),
    "blank lines only": (b"\n\n\n", ("error", r": no data rows")),
    "header only": ((",".join(f"c{i}" for i in range(24)) + "\n").encode(),
                    ("error", r": no data rows")),
    "UTF-16": ("\n".join(paper_csv()).encode("utf-16"), ("error", r":1: not UTF-8 text")),
    "Latin-1 text": (("\n".join(paper_csv()) + "\nné,1\n").encode("latin-1"),
                     ("error", r":13: not UTF-8 text")),
    "NUL bytes": (b"1,2\x00,3\n", ("error", r": contains NUL bytes")),
    "binary junk": (bytes(range(256)) * 4, ("error", r"not UTF-8|NUL")),
    "semicolons, BOM and CRLF (fine)": (("\ufeff" + "\r\n".join(
        line.replace(",", ";") for line in paper_csv())).encode(), ("ok",)),
}


def import_outcome(tmp_path: Path, name: str, data: bytes, policy: str):
    path = tmp_path / f"{re.sub(r'[^a-z0-9]+', '_', name.lower())}.csv"
    path.write_bytes(data)
    try:
        result = import_paper_layout(path, "single_force", bad_rows=policy)
    except DatasetError as err:
        return path, "error", str(err)
    return path, result, ""


@pytest.mark.parametrize("name", IMPORT_CASES)
def test_bad_import_files(tmp_path, name):
    data, expected = IMPORT_CASES[name]
    path, result, message = import_outcome(tmp_path, name, data, "error")
    if expected[0] == "ok":
        assert result != "error", message
        return
    assert result == "error" and message.startswith(str(path)), message
    regex = expected[1] if expected[0] == "error" else expected[2]
    assert re.search(regex, message), message
    if expected[0] == "quarantined":
        _, kept, _ = import_outcome(tmp_path, name, data, "quarantine")
        assert len(kept.quarantine) == expected[1]
        assert len(kept.frame) + len(kept.quarantine) == kept.metadata["source"]["rows_in_file"]
        assert all(row["source"] == str(path) and row["reason"] for row in kept.quarantine)


def test_truncated_and_garbled_parquet_imports(tmp_path):
    frame = pd.DataFrame([[float(v) for v in line.split(",")] for line in paper_csv()])
    frame.columns = [f"c{i}" for i in range(24)]
    whole = tmp_path / "whole.parquet"
    frame.to_parquet(whole)
    for name, data in (("cut", whole.read_bytes()[:200]), ("zeros", bytes(300)),
                       ("csv", b"1,2,3\n")):
        path = tmp_path / f"{name}.parquet"
        path.write_bytes(data)
        with pytest.raises(DatasetError, match=re.escape(str(path)) + ": not a readable Parquet"):
            import_paper_layout(path, "single_force")


# ---------------------------------------------------------------- raw logs

PLAN = single_force_plan("single_force", [1.0], [0.0], samples=2)   # 101 conditions
DEVICE = {"id": "sim-test", "firmware": "sim-x", "terminals": 20, "adc_bits": 10}


def clean_log(path: Path) -> Path:
    session = {"session": "s001", "scene": "single_force", "plan": PLAN.as_dict(),
               "device": DEVICE, "source": "simulated"}
    writer = RawLogWriter(path, session)
    seq = 0
    for condition in PLAN.conditions:
        record = {"key": condition.key(DEVICE["id"], DEVICE["firmware"]),
                  "scene": "single_force", **condition.as_dict()}
        attempt = writer.begin(record)
        frames = [parse_line(encode_frame(seq + i, 12 * (seq + i), [500 + i] * 20)[:-1])
                  for i in range(2)]
        seq += 2
        writer.frames(attempt, frames)
        writer.end(attempt, 2)
    writer.close()
    return path


def replace_line(number: int, new: str):
    def damage(lines):
        lines[number - 1] = new
        return lines
    return damage


def line_edit(number: int, old: str, new: str):
    def damage(lines):
        lines[number - 1] = lines[number - 1].replace(old, new, 1)
        return lines
    return damage


LOG_CASES = {
    # name: (damage to the list of lines, expected error regex under bad_rows: error)
    "empty file": (lambda lines: [], r": no raw log; run `eskin acquire single_force` first"),
    "header only": (lambda lines: lines[:1], r": the raw log has no acquisition session"),
    "not a raw log": (replace_line(1, "time,cx1,cx2"), r":1: not an eskin raw log"),
    "newer format": (replace_line(1, "#eskin-raw 2"), r":1: not an eskin raw log"),
    "frame with a bad CRC": (line_edit(4, ",500,", ",501,"), r":4: stored frame does not verify"),
    "frame with a missing field": (line_edit(5, ",501", ""), r":5: stored frame does not verify"),
    "not ASCII": (line_edit(4, "D,", "D\u00e9,"), r":4: not ASCII"),
    "NUL byte": (line_edit(4, "D,", "D\x00,"), r":4: stored frame does not verify"),
    "bad JSON condition": (line_edit(3, "{", "{{"), r":3: Expecting property name"),
    "unknown record type": (lambda lines: lines[:5] + ["Z\t1\tboo"] + lines[5:],
                            r":6: unknown record type 'Z'"),
    "end count mismatch": (line_edit(6, "\t2", "\t3"), r":6: attempt closed with 3 frames"),
    "record of an attempt never begun": (lambda lines: lines + ["F\t999\tD,1*00"],
                                         r": record for attempt 999 that never began"),
    "attempt begun twice": (lambda lines: lines + [lines[2]], r": attempt 1 began twice"),
    "mixed scenes": (lambda lines: lines + [lines[1].replace('"scene": "single_force"',
                                                            '"scene": "two_force"')],
                     r"sessions of scene\(s\) \['two_force'\] besides single_force"),
    "cut short (conditions missing)": (lambda lines: lines[:200],
                                       r"have no complete recording .*eskin acquire"),
}


def damaged_log(tmp_path: Path, damage) -> Path:
    path = clean_log(tmp_path / "acquisition.log")
    lines = damage(path.read_text(encoding="ascii").splitlines())
    path.write_bytes("".join(line + "\n" for line in lines).encode("utf-8"))
    return path


@pytest.mark.parametrize("name", LOG_CASES)
def test_bad_raw_logs(tmp_path, name):
    damage, regex = LOG_CASES[name]
    path = damaged_log(tmp_path, damage)
    with pytest.raises((DatasetError, RawLogError)) as info:
        ingest_log(path, PLAN, bad_rows="error")
    message = str(info.value)
    assert str(path) in message and re.search(regex, message), message


def test_a_bad_log_line_goes_to_quarantine_and_its_condition_is_asked_again(tmp_path):
    path = damaged_log(tmp_path, line_edit(4, ",500,", ",501,"))
    with pytest.raises(DatasetError, match="1 of 101 planned conditions .*eskin acquire"):
        ingest_log(path, PLAN, bad_rows="quarantine")
    # Junk that taints no condition (a stray record after the end) is only quarantined.
    (tmp_path / "second").mkdir()
    path = damaged_log(tmp_path / "second", lambda lines: lines + ["Z\t1\tboo"])
    result = ingest_log(path, PLAN, bad_rows="quarantine")
    assert len(result.frame) == 202 and len(result.quarantine) == 1
    assert result.quarantine[0]["line"] == 2 + 101 * 4 + 1  # magic, session, 4 per condition


def test_a_torn_last_line_is_not_an_error(tmp_path):
    path = clean_log(tmp_path / "acquisition.log")
    with path.open("ab") as handle:
        handle.write(b'B\t102\t{"key": "x", "st')
    assert len(ingest_log(path, PLAN).frame) == 202


if __name__ == "__main__":  # the catalogue as a table: what each bad file produced
    import tempfile

    with tempfile.TemporaryDirectory() as scratch:
        root = Path(scratch)
        print("| import file | error policy | quarantine policy |\n|---|---|---|")
        for name, (data, _) in IMPORT_CASES.items():
            _, result, message = import_outcome(root, name, data, "error")
            _, kept, quarantined = import_outcome(root, name, data, "quarantine")
            strip = message.replace(scratch + "/", "")
            after = (quarantined.replace(scratch + "/", "") if kept == "error" else
                     f"{len(kept.frame)} rows kept, {len(kept.quarantine)} quarantined")
            print(f"| {name} | {strip or 'imported'} | {after} |")
        print("\n| raw log | ingest says |\n|---|---|")
        for name, (damage, _) in LOG_CASES.items():
            case = root / re.sub(r"[^a-z0-9]+", "_", name)
            case.mkdir()
            path = damaged_log(case, damage)
            try:
                ingest_log(path, PLAN, bad_rows="error")
                said = "ingested"
            except (DatasetError, RawLogError) as err:
                said = str(err).replace(str(case) + "/", "")
            print(f"| {name} | {json.dumps(said, ensure_ascii=False)[1:-1][:160]} |")
