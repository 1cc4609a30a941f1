"""Wire protocol v1: CRC, frame encoding and the sans-I/O parser."""

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from eskin.device.protocol import (
    Frame,
    FrameParser,
    Hello,
    ParseError,
    Reply,
    SequenceBackwards,
    SequenceGap,
    crc8,
    encode_frame,
    parse_line,
)

COUNTS = list(range(0, 1000, 50))


def test_crc8_matches_the_smbus_check_value():
    assert crc8(b"123456789") == 0xF4
    assert crc8(b"") == 0


def test_encoded_frame_parses_back():
    line = encode_frame(7, 1234, COUNTS)
    assert line.endswith(b"\n") and line.count(b"*") == 1
    event = parse_line(line[:-1])
    assert isinstance(event, Frame)
    assert (event.seq, event.t_ms, event.counts) == (7, 1234, tuple(COUNTS))


def test_arduino_crlf_endings_are_accepted():
    events = FrameParser().feed(encode_frame(0, 0, COUNTS)[:-1] + b"\r\n")
    assert isinstance(events[0], Frame)


def test_every_single_byte_change_is_rejected():
    line = encode_frame(12345, 678, COUNTS)[:-1]
    for at in range(len(line)):
        for new in (0x00, 0x20, 0x41, line[at] ^ 0x01, 0xFF):
            if new == line[at] or new == ord("\n"):
                continue
            damaged = line[:at] + bytes([new]) + line[at + 1:]
            assert not isinstance(parse_line(damaged), Frame), (at, new)


def test_truncated_frame_is_a_parse_error_naming_the_problem():
    line = encode_frame(1, 2, COUNTS)
    event = FrameParser().feed(line[:30] + b"\n")[0]
    assert isinstance(event, ParseError)
    assert "truncated" in event.reason or "CRC" in event.reason


def test_out_of_range_reading_is_rejected_even_with_a_good_crc():
    body = b"D,1,2," + b",".join([b"1024"] + [b"0"] * 19)
    event = parse_line(body + b"*%02X" % crc8(body))
    assert isinstance(event, ParseError) and "1023" in event.reason


def test_signs_spaces_and_underscores_are_not_numbers():
    for bad in (b"+5", b" 5", b"1_0", b"-1"):
        body = b"D,1,2," + b",".join([bad] + [b"0"] * 19)
        assert isinstance(parse_line(body + b"*%02X" % crc8(body)), ParseError)


def test_messages_are_parsed():
    hello = parse_line(b"#HELLO eskin 1.2.0 terminals=20 adc_bits=10 id=board-42")
    assert hello == Hello("1.2.0", 20, 10, "board-42", hello.line)
    assert parse_line(b"#OK SAMPLE 20") == Reply(True, "SAMPLE", "20", b"#OK SAMPLE 20")
    err = parse_line(b"#ERR SIM not a simulated board")
    assert isinstance(err, Reply) and not err.ok and err.details == "not a simulated board"
    assert isinstance(parse_line(b"#WHAT"), ParseError)


def test_lost_frames_are_reported_as_a_gap_and_repeats_are_rejected():
    parser = FrameParser()
    events = parser.feed(b"".join(encode_frame(s, 0, COUNTS) for s in (0, 1, 4, 4, 5)))
    kinds = [type(e).__name__ for e in events]
    assert kinds == ["Frame", "Frame", "SequenceGap", "Frame", "SequenceBackwards", "Frame"]
    assert events[2] == SequenceGap(expected=2, got=4)
    # a repeat is a bad line like any other, and a host tells it apart by its type
    assert isinstance(events[4], ParseError) and isinstance(events[4], SequenceBackwards)
    assert not any(isinstance(e, SequenceBackwards) for e in parser.feed(b"D,7,0,1*00\n"))


def test_hello_restarts_the_sequence():
    parser = FrameParser()
    hello = b"#HELLO eskin 1 terminals=20 adc_bits=10 id=a\n"
    events = parser.feed(encode_frame(9, 0, COUNTS) + hello + encode_frame(0, 0, COUNTS))
    assert [type(e) for e in events] == [Frame, Hello, Frame]


def test_runaway_line_without_newline_is_dropped_not_buffered_forever():
    parser = FrameParser()
    events = parser.feed(b"x" * 10_000)
    assert isinstance(events[-1], ParseError)
    # Issue 56: a frame glued to its end goes with it (a read boundary made it parse),
    # and the line after its newline is read as ever.
    glued = parser.feed(encode_frame(0, 0, COUNTS))
    assert [type(e) for e in glued] == [ParseError] and "glued" in glued[0].reason
    assert isinstance(parser.feed(encode_frame(1, 0, COUNTS))[-1], Frame)


def test_lines_that_end_in_cr_only_are_named_as_the_cause():
    """Issue 40: a board whose lines end in CR only sent nothing the parser could end, and
    the host said only that it had lost the board."""
    parser = FrameParser()
    greeting = b"#HELLO eskin 1 terminals=20 adc_bits=10 id=a\r#OK STREAM OFF\r"
    assert parser.feed(greeting) == [] and "lines end in CR only" in parser.line_ending_hint
    frames = b"".join(encode_frame(i, 0, COUNTS).replace(b"\n", b"\r") for i in range(3))
    events = parser.feed(frames)
    assert isinstance(events[0], ParseError) and "lines end in CR only" in events[0].reason
    assert parser.feed(b"\n") and parser.line_ending_hint is None  # an LF: lines end again
    crlf = FrameParser()
    crlf.feed(encode_frame(0, 0, COUNTS)[:-1] + b"\r\n")
    assert crlf.line_ending_hint is None


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=600))
def test_arbitrary_bytes_never_raise_and_never_yield_a_bad_frame(data):
    for event in FrameParser(20).feed(data):
        if isinstance(event, Frame):
            body, _, crc = event.line.rstrip(b"\r").rpartition(b"*")
            assert int(crc, 16) == crc8(body)
            assert len(event.counts) == 20 and max(event.counts) <= 1023


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 2**32 - 1), st.integers(0, 2**32 - 1),
                          st.lists(st.integers(0, 1023), min_size=20, max_size=20)),
                min_size=1, max_size=5),
       st.binary(max_size=80), st.integers(1, 50))
@example(frames=[(0, 0, [0] * 20)] * 3, garbage=b"#HELLO eskin x terminals=2 adc_bits=1 id=s",
         chunk=1)
def test_valid_frames_survive_garbage_between_them_and_any_chunking(frames, garbage, chunk):
    stream = b"".join(garbage + b"\n" + encode_frame(*f) for f in frames)
    parser = FrameParser(20)  # the paper's skin: a #HELLO of another count changes no frame
    events = [e for i in range(0, len(stream), chunk) for e in parser.feed(stream[i:i + chunk])]
    got = [(e.seq, e.t_ms, list(e.counts)) for e in events if isinstance(e, Frame)]
    # garbage may itself hold a newline-free valid frame only with a 1-in-256 CRC chance
    # and the right shape; valid frames are never lost unless they repeat a sequence number.
    # Garbage that happens to be a #HELLO line (Hypothesis draws the source's own string
    # constants) is a board restart, after which the sequence legitimately starts again.
    garbage_is_hello = any(isinstance(e, Hello) for e in FrameParser().feed(garbage + b"\n"))
    expected = []
    last = None
    for seq, t, counts in frames:
        if garbage_is_hello or last is None or seq > last:
            expected.append((seq, t, counts))
        last = seq
    assert [g for g in got if g in expected] == expected


def test_a_frame_carries_the_terminals_the_host_expects():
    wide = encode_frame(0, 0, [1023] * 64)  # a 32 × 32 skin: a line beyond 256 bytes
    assert isinstance(FrameParser(64).feed(wide)[0], Frame)
    refused = FrameParser(20).feed(wide)[0]
    assert isinstance(refused, ParseError) and "longer than 256 bytes" in refused.reason
    narrow = FrameParser(20).feed(encode_frame(0, 0, [500] * 16))[0]
    assert narrow.reason == "frame has 18 fields, expected 22 (seq, t_ms and 20 readings)"
    assert parse_line(encode_frame(0, 0, [500] * 16)[:-1], 16).counts == (500,) * 16


def test_without_an_expected_count_the_parser_takes_the_boards_hello():
    parser = FrameParser()
    events = parser.feed(b"#HELLO eskin fw terminals=64 adc_bits=10 id=a\n"
                         + encode_frame(0, 0, [7] * 64) + encode_frame(1, 0, [7] * 20))
    assert [type(e) for e in events] == [Hello, Frame, ParseError]
    assert parser.terminals == 64 and "expected 66" in events[2].reason


@pytest.mark.parametrize("count", [0, 65])
def test_a_hello_beyond_protocol_v1s_terminals_is_not_trusted(count):
    event = parse_line(b"#HELLO eskin fw terminals=%d adc_bits=10 id=a" % count)
    assert isinstance(event, ParseError) and "protocol v1 carries 1..64" in event.reason
