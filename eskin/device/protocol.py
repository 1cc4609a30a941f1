"""Wire protocol v1 between an e-skin board and the host, as pure code.

The parser is sans-I/O (after h11): it is fed bytes from anywhere — a serial
port, a pseudo-terminal, a socket, a recorded log — and returns events. It
never reads a port and never raises on bad input: malformed lines, failed
CRCs and broken sequences come out as :class:`ParseError` (a sequence that went back:
:class:`SequenceBackwards`) and :class:`SequenceGap` events, so one noisy line never costs
the session.

Frame line (board → host)::

    D,<seq>,<t_ms>,<a1>,...,<aN>*<CC>\\n

N is the board's terminals (its ``#HELLO`` says ``terminals=N``: rows then columns of a
row/column skin, 20 on the paper's 10 × 10). The parser checks a frame against the N the
host expects, the skin it reads; without one, against the N of the board's ``#HELLO``.
``CC`` is the CRC-8 (polynomial 0x07, init 0x00) of every byte before ``*``
in two upper-case hex digits. ``\\r\\n`` endings (Arduino ``println``) are
accepted.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field

ADC_MAX = 1023
SEQ_MAX = 2**32 - 1
MAX_TERMINALS = 64  # a 32 × 32 row/column skin, the largest (eskin.skin.Skin)
# Longest command line, and longest line of a board of up to 46 terminals: anything much
# longer without a newline is garbage; drop it rather than buffer forever.
MAX_LINE_BYTES = 256


def max_line_bytes(terminals: int) -> int:
    """The longest line a board of ``terminals`` sends, newline aside: its longest frame
    ("D," + 2 × 10-digit counters and a comma + N × (comma + 4 digits) + "*CC"), or
    :data:`MAX_LINE_BYTES` if that is longer."""
    return max(MAX_LINE_BYTES, 2 + 10 + 1 + 10 + 5 * terminals + 3)
# What a board whose lines end in CR alone (``\r``, no ``\n``) is told: the parser never
# sees a line end, so all it would say otherwise is that nothing came, or junk.
CR_ONLY_HINT = "its lines end in CR only: protocol v1 ends each line with LF (\\n)"


def _crc8_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


_CRC8_TABLE = _crc8_table()


def crc8(data: bytes) -> int:
    """CRC-8 with polynomial 0x07 and initial value 0x00 (CRC-8/SMBUS).

    >>> hex(crc8(b"123456789"))
    '0xf4'
    """
    crc = 0
    for byte in data:
        crc = _CRC8_TABLE[crc ^ byte]
    return crc


def encode_frame(seq: int, t_ms: int, counts: Sequence[int]) -> bytes:
    """Encode one frame line (one reading per terminal), newline included."""
    body = b"D,%d,%d," % (seq, t_ms) + b",".join(b"%d" % c for c in counts)
    return body + b"*%02X\n" % crc8(body)


# ---------------------------------------------------------------- events


@dataclass(frozen=True)
class Frame:
    """One verified frame: CRC correct, every field in range."""

    seq: int
    t_ms: int
    counts: tuple[int, ...]
    line: bytes = field(repr=False)


# The id a board's firmware reports until it is given one (``ID <id>``, once, into its
# EEPROM; firmware/eskin). Two such boards cannot be told apart, so a real acquisition
# refuses it (eskin device set-id gives one).
UNSET_ID = "unset"


@dataclass(frozen=True)
class Hello:
    """``#HELLO eskin <fw> terminals=<N> adc_bits=10 id=<device-id>``."""

    firmware: str
    terminals: int
    adc_bits: int
    device_id: str
    line: bytes = field(repr=False)


@dataclass(frozen=True)
class Reply:
    """``#OK <command> [details]`` or ``#ERR <command> <reason>``."""

    ok: bool
    command: str
    details: str
    line: bytes = field(repr=False)


@dataclass(frozen=True)
class ParseError:
    """A line that could not be trusted; ``line`` is what arrived."""

    reason: str
    line: bytes


@dataclass(frozen=True)
class SequenceBackwards(ParseError):
    """A frame whose seq did not pass the last one's: the board's count started again (a
    restart whose ``#HELLO`` was lost) or an old frame was replayed. Never delivered; a
    host tells it from other bad lines by its type."""


@dataclass(frozen=True)
class SequenceGap:
    """Frames were lost: ``got`` arrived where ``expected`` was due."""

    expected: int
    got: int


Event = Frame | Hello | Reply | ParseError | SequenceGap

_DIGITS = re.compile(rb"[0-9]{1,10}\Z")
_HELLO = re.compile(
    rb"#HELLO eskin (?P<fw>\S+) terminals=(?P<t>[0-9]+) adc_bits=(?P<b>[0-9]+) id=(?P<id>\S+)\Z"
)


def parse_line(line: bytes, terminals: int | None = None) -> Frame | Hello | Reply | ParseError:
    """Parse one line (without its newline) into an event. Never raises. A frame must carry
    ``terminals`` readings; None takes a frame of any width (one line out of context)."""
    if line.endswith(b"\r"):
        line = line[:-1]
    if line.startswith(b"D,"):
        return _parse_frame(line, terminals)
    if line.startswith(b"#"):
        return _parse_message(line)
    if not line:
        return ParseError("empty line", line)
    return ParseError("line is neither a frame (D,...) nor a message (#...)", line)


def _parse_frame(line: bytes, terminals: int | None) -> Frame | ParseError:
    body, star, crc_text = line.rpartition(b"*")
    if not star:
        return ParseError("frame has no '*<CRC>' trailer (truncated?)", line)
    if len(crc_text) != 2 or not all(c in b"0123456789ABCDEF" for c in crc_text):
        return ParseError("CRC is not two upper-case hex digits", line)
    if int(crc_text, 16) != crc8(body):
        return ParseError(f"CRC mismatch: line says {crc_text.decode()}, bytes give "
                          f"{crc8(body):02X}", line)
    fields = body.split(b",")[1:]
    if terminals is not None and len(fields) != 2 + terminals:
        return ParseError(f"frame has {len(fields)} fields, expected {2 + terminals} "
                          f"(seq, t_ms and {terminals} readings)", line)
    if len(fields) < 3:
        return ParseError(f"frame has {len(fields)} fields: seq, t_ms and no reading", line)
    if not all(_DIGITS.match(f) for f in fields):
        return ParseError("frame field is not an unsigned decimal integer", line)
    seq, t_ms, *counts = (int(f) for f in fields)
    if seq > SEQ_MAX or t_ms > SEQ_MAX:
        return ParseError("seq or t_ms exceeds 32 bits", line)
    if max(counts) > ADC_MAX:
        return ParseError(f"ADC reading above {ADC_MAX}", line)
    return Frame(seq, t_ms, tuple(counts), line)


def _parse_message(line: bytes) -> Hello | Reply | ParseError:
    try:
        text = line.decode("ascii")
    except UnicodeDecodeError:
        return ParseError("message is not ASCII", line)
    if text.startswith("#HELLO"):
        match = _HELLO.match(line)
        if not match:
            return ParseError("malformed #HELLO", line)
        if not 1 <= int(match["t"]) <= MAX_TERMINALS:
            return ParseError(f"#HELLO says terminals={int(match['t'])}: protocol v1 carries "
                              f"1..{MAX_TERMINALS}", line)
        return Hello(match["fw"].decode(), int(match["t"]), int(match["b"]),
                     match["id"].decode(), line)
    for prefix, ok in (("#OK ", True), ("#ERR ", False)):
        if text.startswith(prefix):
            command, _, details = text[len(prefix):].partition(" ")
            if command:
                return Reply(ok, command, details, line)
    return ParseError("unknown message", line)


class FrameParser:
    """Incremental protocol-v1 parser: ``feed(bytes) -> list[Event]``.

    Keeps the partial last line between calls and the last sequence number,
    so it can report lost frames. A ``#HELLO`` (board start or reset) resets
    the sequence expectation, since the counter restarts at power-up.

    ``terminals``: the readings a frame must carry, the skin the host expects (a board
    that says otherwise is the host's to refuse: its frames fail here). None: as many
    as the last ``#HELLO`` said (before one, a frame of any width, in a line of at most
    :data:`MAX_LINE_BYTES`).
    """

    def __init__(self, terminals: int | None = None) -> None:
        self.terminals = terminals
        self._expects = terminals is not None
        self._max_line = MAX_LINE_BYTES if terminals is None else max_line_bytes(terminals)
        self._buffer = bytearray()
        # A line grew past the longest the protocol allows: everything up to its newline
        # is dropped, whatever is glued to its end (a frame, say): by the line rule that
        # frame was lost, and a read boundary must not make it parse.
        self._discarding = False
        self._last_seq: int | None = None
        self._cr_since_lf = False  # a CR came since the last LF: CR-only line endings?

    @property
    def line_ending_hint(self) -> str | None:
        """:data:`CR_ONLY_HINT` when CRs have come since the last LF (a board that ends
        its lines in CR only), else None."""
        return CR_ONLY_HINT if self._cr_since_lf else None

    def reset_sequence(self) -> None:
        """Forget the last sequence number (after a reconnect, say)."""
        self._last_seq = None

    def feed(self, data: bytes) -> list[Event]:
        events: list[Event] = []
        self._buffer += data
        while True:
            end = self._buffer.find(b"\n")
            if end < 0:
                break
            line = bytes(self._buffer[:end])
            del self._buffer[: end + 1]
            self._cr_since_lf = False
            if self._discarding:
                self._discarding = False
                events.append(ParseError(
                    f"end of a line longer than {self._max_line} bytes, dropped up to its "
                    "newline with whatever was glued to it", line))
                continue
            if len(line) > self._max_line:
                events.append(ParseError(f"line longer than {self._max_line} bytes", line))
                continue
            self._handle(parse_line(line, self.terminals), events)
        self._cr_since_lf = self._cr_since_lf or b"\r" in self._buffer
        if len(self._buffer) > self._max_line:
            hint = f" ({CR_ONLY_HINT})" if self._cr_since_lf else ""
            events.append(ParseError(f"no newline within {self._max_line} bytes{hint}",
                                     bytes(self._buffer)))
            self._buffer.clear()
            self._discarding = True
        return events

    def _handle(self, event: Frame | Hello | Reply | ParseError, events: list[Event]) -> None:
        if isinstance(event, Hello):
            self._last_seq = None
            if not self._expects:
                self.terminals = event.terminals
                self._max_line = max_line_bytes(event.terminals)
        elif isinstance(event, Frame):
            last = self._last_seq
            if last is not None and event.seq <= last:
                # Never deliver it, but follow the new count so that a board reset whose
                # #HELLO was lost costs one frame, not the rest of the session.
                self._last_seq = event.seq
                events.append(SequenceBackwards(
                    f"sequence went backwards or repeated: {event.seq} after {last}",
                    event.line))
                return
            if last is not None and event.seq != last + 1:
                events.append(SequenceGap(last + 1, event.seq))
            self._last_seq = event.seq
        events.append(event)
