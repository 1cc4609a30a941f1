"""The raw acquisition log: append-only, line-oriented, flushed per condition.

One text file per scene, one record per line, fields separated by tabs::

    #eskin-raw 1
    S <json session: id, scene, source, port, device, simulator; "mode": "live" for a
       live recording, whose conditions are chunks of the stream, not the plan's>
    B <attempt> <json condition: key, stretch, contacts>
    F <attempt> <frame line exactly as received>
    R <attempt> <reason> <json string of the rejected bytes>
    E <attempt> <frames>           condition complete
    X <attempt> <reason>           attempt abandoned (it will be asked again)

Every frame line is kept as it arrived, the rejected ones too (the first
64 of each attempt: a board that floods junk cannot fill the disk; the
acquisition summary counts them all), so the log is the evidence. Only
attempts closed by ``E`` count. A condition whose frames came from several
attempts (each answer's valid frames kept, the rest asked again) is closed
by a record of its own: ``B`` with ``"assembled_from"``, the attempts its frames
came from, then those frames in their places, copied from those attempts'
``F`` lines, then ``E``. After a crash the last line may be torn;
reading ignores it and reopening for append cuts it off, so a restart
resumes at the first incomplete condition and loses nothing that was flushed.

The file comes into being with its header, atomically (written aside, then
renamed), when the first attempt begins: an interruption before that leaves
no file, never an empty or headerless one. A 0-byte log (left by eskin
before this rule) counts as no log, and a log whose header was lost that way
(it starts with its session record) is read, and repaired on the next append.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from eskin.device.protocol import Frame, ParseError, parse_line
from eskin.errors import EskinError

MAGIC = "#eskin-raw 1"


LOG_NAME = "acquisition.log"  # data/raw/<scene>/acquisition.log


class RawLogError(EskinError, ValueError):
    """A raw log line that cannot be trusted; names the file and the line."""


@dataclass
class Attempt:
    number: int
    session: dict
    condition: dict
    frames: list[Frame] = field(default_factory=list)


@dataclass
class BadLine:
    path: Path
    line_number: int
    reason: str
    text: str

    def __str__(self) -> str:
        return f"{self.path}:{self.line_number}: {self.reason}: {self.text[:120]!r}"


@dataclass
class LogContents:
    sessions: list[dict]
    completed: dict[str, Attempt]  # condition key -> latest completed attempt
    attempts: int
    frames_rejected: int
    bad_lines: list[BadLine]
    torn_tail: bool
    headerless: bool = False


def read_log(path: Path) -> LogContents:
    """Read a raw log. Lines that break the format are collected in ``bad_lines``,
    and an attempt holding one does not count as complete."""
    path = Path(path)
    sessions: list[dict] = []
    attempts: dict[int, Attempt] = {}
    completed: dict[str, Attempt] = {}
    bad: list[BadLine] = []
    tainted: set[int] = set()
    rejected = 0
    torn = headerless = False
    with path.open("rb") as handle:
        for number, raw in enumerate(handle, start=1):
            if not raw.endswith(b"\n"):
                torn = True  # an interrupted write: at most the last line
                break
            try:
                line = raw[:-1].decode("ascii")
            except UnicodeDecodeError:
                bad.append(BadLine(path, number, "not ASCII", raw.decode("latin-1")))
                continue
            if number == 1 and line.startswith("S\t{"):
                headerless = True  # the header an interrupted first run lost; read on
            elif number == 1:
                if line != MAGIC:
                    raise RawLogError(f"{path}:1: not an eskin raw log (first line {line[:40]!r},"
                                      f" expected {MAGIC!r})")
                continue
            tag, _, rest = line.partition("\t")
            try:
                if tag == "S":
                    sessions.append(json.loads(rest))
                    continue
                if not sessions:
                    raise ValueError("record before any session header")
                number_text, _, payload = rest.partition("\t")
                attempt_no = int(number_text)
                if tag == "B":
                    if attempt_no in attempts:
                        raise ValueError(f"attempt {attempt_no} began twice (log edited "
                                         "or joined from two files?)")
                    condition = json.loads(payload)
                    if "key" not in condition:
                        raise ValueError("condition without key")
                    attempts[attempt_no] = Attempt(attempt_no, sessions[-1], condition)
                    continue
                attempt = attempts.get(attempt_no)
                if attempt is None:
                    raise ValueError(f"record for attempt {attempt_no} that never began")
                if tag == "F":
                    # As many readings as the session's board said it has terminals.
                    terminals = attempt.session.get("device", {}).get("terminals")
                    if not isinstance(terminals, int):
                        raise ValueError("its session record gives no device terminals")
                    event = parse_line(payload.encode("ascii"), terminals)
                    if isinstance(event, ParseError) or not isinstance(event, Frame):
                        reason = event.reason if isinstance(event, ParseError) else "not a frame"
                        raise ValueError(f"stored frame does not verify: {reason}")
                    attempt.frames.append(event)
                elif tag == "R":
                    rejected += 1
                elif tag == "E" and attempt_no not in tainted:  # a tainted one is reported
                    if int(payload) != len(attempt.frames):
                        raise ValueError(f"attempt closed with {payload} frames but "
                                         f"{len(attempt.frames)} are stored")
                    completed[attempt.condition["key"]] = attempt
                elif tag not in ("E", "X"):
                    raise ValueError(f"unknown record type {tag!r}")
            except (ValueError, KeyError, TypeError) as err:
                bad.append(BadLine(path, number, str(err), line))
                if tag in ("B", "F", "R", "E", "X") and rest.partition("\t")[0].isdigit():
                    tainted.add(int(rest.partition("\t")[0]))
    return LogContents(sessions, completed, max(attempts, default=0), rejected, bad, torn,
                       headerless)


def acquisition_sessions(contents: LogContents) -> list[dict]:
    """The sessions that acquired a plan's conditions, in order: not the live recordings
    (``eskin live --record``, ``"mode": "live"``), which are no plan's."""
    return [s for s in contents.sessions if s.get("mode") != "live"]


def read_log_if_any(path: Path) -> LogContents | None:
    """The log at ``path``, or None if there is none yet (absent, or 0 bytes)."""
    path = Path(path)
    if not path.exists() or path.stat().st_size == 0:
        return None
    return read_log(path)


class RawLogWriter:
    """Appends to a raw log; opening repairs a torn last line first, and the session
    header goes in with the session's first attempt."""

    def __init__(self, path: Path, session: dict, contents: LogContents | None = None) -> None:
        """``contents``: the log as already read (``read_log``), if the caller has it."""
        self.path = Path(path)
        if contents is None:
            contents = read_log_if_any(self.path)
        if contents is not None and contents.torn_tail:
            _cut_torn_tail(self.path)  # a repair, done on opening as before any append
        self._contents = contents
        self.attempt = contents.attempts if contents else 0
        self._session: dict | None = session  # written with the first attempt
        self._file = None  # opened at the first attempt: a session that records nothing
        self.open_attempt: int | None = None  # begun, neither ended nor abandoned yet

    def _open(self):
        """The file, for append, valid from its first byte."""
        contents = self._contents
        if contents is None:
            # A new log (or a 0-byte one): header written aside and renamed into place.
            _replace_atomically(self.path, MAGIC + "\n")
        elif contents.headerless:
            _replace_atomically(self.path, MAGIC + "\n" + self.path.read_text("ascii"))
        return self.path.open("a", encoding="ascii", newline="\n")

    def _write(self, *fields: object) -> None:
        self._file.write("\t".join(str(f) for f in fields) + "\n")

    def begin(self, condition: dict) -> int:
        # A session that acquires nothing leaves the log untouched, byte for byte.
        if self._file is None:
            self._file = self._open()
        if self._session is not None:
            self._write("S", json.dumps(self._session, sort_keys=True))
            self._session = None
        self.attempt += 1
        self._write("B", self.attempt, json.dumps(condition, sort_keys=True))
        self.open_attempt = self.attempt
        return self.attempt

    def frames(self, attempt: int, frames: list[Frame]) -> None:
        for frame in frames:
            self._write("F", attempt, frame.line.decode("ascii"))

    def rejected(self, attempt: int, errors: list[ParseError]) -> None:
        for error in errors:
            self._write("R", attempt, _ascii_field(error.reason),
                        json.dumps(error.line.decode("latin-1")))

    def end(self, attempt: int, n_frames: int) -> None:
        self._write("E", attempt, n_frames)
        self.open_attempt = None
        self.flush()

    def assemble(self, condition: dict, frames: list[Frame], attempts: list[int]) -> int:
        """Close a condition with ``frames``, its samples in order, taken from the (already
        logged) ``attempts``: a record of its own, complete."""
        attempt = self.begin({**condition, "assembled_from": attempts})
        self.frames(attempt, frames)
        self.end(attempt, len(frames))
        return attempt

    def abandon(self, attempt: int, reason: str) -> None:
        self._write("X", attempt, _ascii_field(reason))
        self.open_attempt = None
        self.flush()

    def flush(self) -> None:
        if self._file is not None:
            self._file.flush()

    def close(self) -> None:
        if self._file is not None:
            self._file.flush()
            os.fsync(self._file.fileno())
            self._file.close()
            self._file = None


def _ascii_field(text: str) -> str:
    """Free text as one field of an ASCII line (a port name or a message may not be)."""
    return text.replace("\t", " ").replace("\n", " ").encode("ascii", "backslashreplace").decode()


def _replace_atomically(path: Path, text: str) -> None:
    """``path`` holds ``text`` or what it held before, never part of it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    aside = path.with_name(path.name + ".partial")
    with aside.open("w", encoding="ascii", newline="\n") as handle:
        handle.write(text)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(aside, path)


def _cut_torn_tail(path: Path) -> None:
    data = path.read_bytes()
    with path.open("r+b") as handle:
        handle.truncate(data.rfind(b"\n") + 1)
