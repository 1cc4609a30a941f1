"""A small sample of the fuzzers `make bench` runs at 100,000 inputs each (harness/fuzz.py)."""

import pytest

from harness import fuzz


@pytest.mark.heavy
def test_frame_parser_survives_damaged_streams():
    result = fuzz.fuzz_parser(300)
    assert result["inputs"] == 300 and result["intact frames"] > 300


@pytest.mark.heavy
def test_import_reader_errors_name_the_file_or_account_for_every_row():
    result = fuzz.fuzz_import(200)
    assert result["inputs"] == 200
    assert result["ok"] and result["quarantine"] and result["error"], result


def test_the_reference_frame_check_agrees_on_known_lines():
    from eskin.device.protocol import encode_frame

    line = encode_frame(5, 60, [0] * 19 + [1023])[:-1]
    assert fuzz.reference_frame_ok(line) and fuzz.reference_frame_ok(line + b"\r")
    assert not fuzz.reference_frame_ok(line.replace(b"1023", b"1024"))
    assert not fuzz.reference_frame_ok(line[:-1] + (b"0" if line[-1:] != b"0" else b"1"))
