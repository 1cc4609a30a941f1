"""An independent protocol-v1 board that misbehaves on cue, for the host's tests.

Written from the protocol's text alone (docs/protocol.md): it imports nothing from
``eskin`` (its own CRC-8, its own frame encoding, its own command parser), so
the host is tested against a counterpart that does not share its mistakes. Its skin
has ``rows`` × ``columns`` terminals (the paper's 10 × 10 unless told): it announces
``terminals=rows+columns`` and sends that many readings, x1..xR then y1..yC.
It speaks the simulated-board extension too (``SIM CLEAR``, ``SIM TRIAL n``,
``SIM PRESS x y N``, ``SIM REPLAY i``, ``SIM PICK n i j ...``), so readings are a function
of the trial, the stretch, the presses and the sample index (from 0 at ``SIM TRIAL``, from
i at ``SIM REPLAY i``, i, j, ... after ``SIM PICK``): a condition asked again reads the
same, and a run with misbehaviours can be compared row by row with an honest one.
``picks=False`` makes it a board older than ``SIM PICK`` (it answers ``#ERR``).
``damage_rate``: each frame line it sends goes out damaged (its CRC wrong) with that
probability, from its own seeded stream. ``frames_asked`` counts the frames its
``SAMPLE`` requests asked for.

Misbehaviours, each at the ``at``-th ``SAMPLE`` request (1-based):

* ``other_board``: half-way through the answer, another board's ``#HELLO``;
  from then on that board answers (its own id, its sequence from 0);
* ``replay``: the previous answer's lines again before the right one;
* ``early_ok``: ``#OK SAMPLE n`` before the n-th frame;
* ``lagging``: from then on, ``#OK SAMPLE n`` before the n-th frame, which
  it holds back and sends first in its next answer (every answer n frames
  long, each shifted by one);
* ``extra_frame``: n + 1 frames, then ``#OK``;
* ``restart_after_ok``: a whole answer, then at once a restart (stretch and
  presses forgotten, its ``#HELLO``);
* ``trickle``: from then on, one junk byte every 100 ms and no answer;
* ``flood``: from then on, frames as fast as the line takes them, no answer;
* ``silent``: no answer at all to that request (the host gives up on it and
  reconnects), then answers as before;
* ``last_lost``: the answer's last frame damaged on the line (its CRC wrong);
* ``restart_mid``: that request and the ``times`` - 1 after it are each cut short by a
  restart half-way through the answer (its first n // 2 frames, then ``#HELLO``; the
  stretch and presses forgotten, the sequence from 0), then it answers as before;
* ``restart_unheard``: a restart half-way through that request's answer whose ``#HELLO``
  is lost: its first n // 2 frames, then the next frame cut short by the reset, the
  ``#HELLO`` glued to it on the same line; the stretch, presses and trial forgotten, the
  sequence and the clock from 0 (a reset tears the line being sent);
* ``damage_each``: every answer in that request's trial (``SIM TRIAL`` of the same
  number again included) goes out with every other frame damaged: those of even
  sample index in the first answer, of odd index in the next, and so on, so no
  answer is ever whole;
* ``time_back``: the answer's first frame says ``t_ms`` 0, its CRC right (digits
  lost in a frame whose CRC-8 matched by chance); its seq goes in ``time_back``;
* ``long_line``: a 1 MiB junk line, ended by a newline, before the answer;
* ``cr_only``: from then on, every line it sends ends in CR only (``\r``);
* ``dup_ok``: the answer whole, and its ``#OK SAMPLE n`` sent again at the start of the
  next ``SAMPLE``'s answer, a pause (:data:`PAUSE`) between them, as a line paced at
  115,200 baud would leave it: the duplicate arrives alone, before that answer's frames;
* ``spoof_ok``: an ``#OK SAMPLE n`` after the first n // 2 frames, then a pause, the rest
  and the real ``#OK``;
* ``lost_ok``: the answer whole, its ``#OK`` lost on the line (never sent);
* ``lose_place``: in that request's trial, the frame of sample index 1 goes out damaged
  the first 5 times it is sent (a place the line keeps losing);
* ``glued_long_line``: 64 KiB of NULs with no newline, then 300 more, each burst followed
  by a pause (so that a read ends where the burst does), then the answer, its first frame
  glued to the end of that line; its seq goes in ``glued``;
* ``time_jump``: the answer's last frame says a ``t_ms`` 100,000 ms later, its CRC right;
  its seq goes in ``time_jumped`` (the next frame, the next answer's, judges it);
* ``time_back_twice``: the answer's last frame says ``t_ms`` 0, and the next answer's
  first a tenth of its own (a digit lost), both CRCs right: the second is below the
  true time but above the first fallen one; both seqs go in ``time_back``;
* ``refuse``: ``#ERR SAMPLE busy`` instead of an answer.

``damage_first``: the first frame of the first answer after each greeting (``HELLO``
asked, or its own restart) goes out damaged (its CRC wrong), when the host has no
sequence number to place the answer by; combine it with any misbehaviour.

``STREAM ON`` starts a frame every 12 ms until ``STREAM OFF``, answers interleaved;
``sent`` keeps every streamed frame as (seq, counts). Misbehaviour while streaming, at
the ``at``-th streamed frame:

* ``stream_other_board``: another board's ``#HELLO``, and its frames from then on (its
  own id, its sequence from 0);
* ``stream_junk``: from then on a junk line where each frame was due (it still answers
  commands, so reconnecting finds it);
* ``stream_cr_only``: from then on, every line it sends ends in CR only;
* ``stream_time_back``: that frame says ``t_ms`` 0, its CRC right; its seq goes in
  ``time_back``.
"""

from __future__ import annotations

import hashlib
import os
import random
import select
import socket
import threading
import time
import tty


def crc8(data: bytes) -> int:
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


def frame_line(seq: int, t_ms: int, counts: list[int]) -> bytes:
    body = (f"D,{seq},{t_ms}," + ",".join(str(c) for c in counts)).encode()
    return body + b"*" + (f"{crc8(body):02X}").encode() + b"\n"


def damaged(line: bytes) -> bytes:
    """A frame line as the wire may leave it: the same bytes, its CRC wrong."""
    body = line.rstrip(b"\n").rpartition(b"*")[0]
    return body + b"*" + (f"{crc8(body) ^ 0xFF:02X}").encode() + b"\n"


def time_fallen(line: bytes, to=lambda t_ms: 0) -> bytes:
    """A frame line with ``t_ms`` 0 (or ``to(t_ms)``) and its CRC made right again."""
    _, seq, t_ms, rest = line.rstrip(b"\n").rpartition(b"*")[0].split(b",", 3)
    body = b"D," + seq + b",%d," % to(int(t_ms)) + rest
    return body + b"*" + (f"{crc8(body):02X}").encode() + b"\n"


LONG_LINE = b"~" * (1 << 20) + b"\n"  # 1 MiB of junk in one line
# In what the board answers: the bytes before it go out, then 50 ms of silence, then the
# rest (what a slow line does between two writes: they arrive in separate reads).
PAUSE = b"\x00<pause>\x00"
PAUSE_S = 0.05


class HostileBoard:
    def __init__(self, *, device_id: str = "hostile-0001", misbehaviour: str | None = None,
                 at: int = 50, times: int = 1, damage_first: bool = False,
                 rows: int = 10, columns: int = 10, picks: bool = True,
                 damage_rate: float = 0.0, seed: int = 0) -> None:
        self.device_id = device_id
        self.rows = rows
        self.terminals = rows + columns
        self.misbehaviour = misbehaviour
        self.at = at
        self.times = times           # restart_mid: how many requests in a row
        self.damage_first = damage_first
        self.greeted = False         # greeted since its last answer: damage_first is due
        self.cr_only = False         # its lines end in CR only
        self.time_back: list[int] = []  # seqs sent with t_ms 0 and a right CRC
        self.time_jumped: list[int] = []  # seqs sent with t_ms jumped forward, CRC right
        self.fall_next = False       # time_back_twice: the next answer's first frame falls
        self.glued: list[int] = []   # glued_long_line: seqs glued to an overlong line
        self.lose_trial: int | None = None  # lose_place: the trial whose index 1 is lost
        self.lost_sends = 0                 # and how many times it was so far
        self.picks = picks
        self.pick: list[int] = []    # SIM PICK: the sample indexes of the next answer
        self.damage_rate = damage_rate
        self._random = random.Random(seed)
        self.frames_asked = 0
        self.junk_due = False        # stream_junk: a junk line where each frame was due
        self.samples_asked = 0
        self.seq = 0
        self.t_ms = 0
        self.stretch_mm = "0"
        self.trial = 0
        self.presses: list[tuple[str, str, str]] = []
        self.index = 0               # sample index within the trial
        self.last_answer = b""
        self.hijacked = False        # another board has taken over the line
        self.gone_wild = False       # trickle / flood: never answers again
        self.held = b""              # lagging: the frame held back for the next answer
        self.damage_trial: int | None = None  # damage_each: the trial whose answers
        self.damaged_answers = 0               # are damaged, and how many so far
        self.streaming = False
        self.streamed = 0
        self.sent: list[tuple[int, list[int]]] = []  # streamed frames: (seq, counts)
        self.ok_due = b""            # dup_ok: the #OK to send again before the next answer
        self._inbox = b""

    # ---------------------------------------------------------------- readings

    def counts(self, other: bool) -> list[int]:
        if other:
            return [777] * self.terminals
        key = f"{self.trial}|{self.stretch_mm}|{sorted(self.presses)}|{self.index}"
        digest = hashlib.sha256(key.encode()).digest() * 2  # 64 bytes: one per terminal
        pressed = ({int(x) for x, _, _ in self.presses}
                   | {self.rows + int(y) for _, y, _ in self.presses})
        return [500 + 7 * (t % 50) + digest[t] % 9 + (120 if t + 1 in pressed else 0)
                for t in range(self.terminals)]

    def frame(self) -> bytes:
        if self.pick:
            self.index = self.pick.pop(0)
        line = frame_line(self.seq, self.t_ms, self.counts(self.hijacked))
        self.seq += 1
        self.t_ms += 12
        self.index += 1
        return line

    def indexed_frame(self) -> tuple[int, bytes]:
        """The next frame and its sample index."""
        line = self.frame()
        return self.index - 1, line

    def hello(self) -> bytes:
        who = "OTHER-9999" if self.hijacked else self.device_id
        return (f"#HELLO eskin hostile-1.0 terminals={self.terminals} adc_bits=10 "
                f"id={who}\n").encode()

    # ---------------------------------------------------------------- commands

    def handle(self, line: bytes) -> bytes:
        words = line.decode("ascii", "replace").split()
        if not words or self.gone_wild:
            return b""
        name = words[0].upper()
        if name == "HELLO":
            self.greeted = True
            return self.hello()
        if name == "STREAM":
            self.streaming = words[1].upper() == "ON"
            return f"#OK STREAM {words[1].upper()}\n".encode()
        if name == "STRETCH":
            self.stretch_mm = words[1]
            self.t_ms += 500
            return f"#OK STRETCH {words[1]}\n".encode()
        if name == "SIM" and len(words) >= 2:
            sub = words[1].upper()
            if sub == "CLEAR":
                self.presses = []
            elif sub == "TRIAL":
                self.trial, self.index, self.pick = int(words[2]), 0, []
            elif sub == "PRESS":
                self.presses.append((words[2], words[3], words[4]))
            elif sub == "REPLAY":
                self.index, self.pick = int(words[2]), []
            elif sub == "PICK":
                if not self.picks:
                    return b"#ERR SIM unknown command\n"
                self.pick = [int(w) for w in words[3:]]
            return f"#OK SIM {sub}\n".encode()
        if name == "SAMPLE":
            return self.sample(int(words[1]))
        return f"#ERR {name} unknown command\n".encode()

    def sample(self, n: int) -> bytes:
        due, self.ok_due = self.ok_due, b""
        self.frames_asked += n
        out = self._sample(n)
        if self.damage_rate:
            out = b"".join(damaged(line) if line.startswith(b"D,")
                           and self._random.random() < self.damage_rate else line
                           for line in out.splitlines(keepends=True))
        return due + out

    def _sample(self, n: int) -> bytes:
        self.samples_asked += 1
        cue = self.misbehaviour if self.samples_asked == self.at else None
        ok = b"#OK SAMPLE %d\n" % n
        if cue in ("trickle", "flood"):
            self.gone_wild = True
            return b""
        if cue == "silent":
            return b""
        if cue == "refuse":
            return b"#ERR SAMPLE busy\n"
        if cue == "cr_only":
            self.cr_only = True
        if (self.misbehaviour == "restart_mid"
                and self.at <= self.samples_asked < self.at + self.times):
            half = b"".join(self.frame() for _ in range(n // 2))
            self.stretch_mm, self.presses, self.trial, self.seq = "0", [], 0, 0
            self.greeted = True
            return half + self.hello()
        if cue == "restart_unheard":
            half = b"".join(self.frame() for _ in range(n // 2))
            torn = self.frame()[:40]
            self.stretch_mm, self.presses, self.trial, self.seq, self.t_ms = "0", [], 0, 0, 0
            return half + torn + self.hello()
        greeted, self.greeted = self.greeted, False
        if greeted and self.damage_first:
            first = damaged(self.frame())
            return first + b"".join(self.frame() for _ in range(n - 1)) + ok
        if cue == "last_lost":
            frames = [self.frame() for _ in range(n)]
            return b"".join(frames[:-1]) + damaged(frames[-1]) + ok
        if cue == "lose_place":
            self.lose_trial = self.trial
        if self.lose_trial is not None and self.trial == self.lose_trial:
            out = []
            for _ in range(n):
                index, line = self.indexed_frame()
                if index == 1 and self.lost_sends < 5:
                    self.lost_sends += 1
                    line = damaged(line)
                out.append(line)
            return b"".join(out) + ok
        if cue == "damage_each":
            self.damage_trial = self.trial
        if self.damage_trial is not None and self.trial == self.damage_trial:
            parity = self.damaged_answers % 2
            self.damaged_answers += 1
            frames = [self.indexed_frame() for _ in range(n)]
            return b"".join(damaged(line) if index % 2 == parity else line
                            for index, line in frames) + ok
        if cue == "time_back":
            self.time_back.append(self.seq)
            first = time_fallen(self.frame())
            return first + b"".join(self.frame() for _ in range(n - 1)) + ok
        if cue == "time_jump":
            frames = [self.frame() for _ in range(n)]
            self.time_jumped.append(self.seq - 1)
            return (b"".join(frames[:-1]) + time_fallen(frames[-1], lambda t: t + 100_000)
                    + ok)
        if cue == "time_back_twice" or self.fall_next:
            frames = [self.frame() for _ in range(n)]
            at = 0 if self.fall_next else n - 1
            self.time_back.append(self.seq - n + at)
            frames[at] = time_fallen(frames[at], (lambda t: t // 10) if self.fall_next
                                     else (lambda t: 0))
            self.fall_next = not self.fall_next
            return b"".join(frames) + ok
        if cue == "glued_long_line":
            self.glued.append(self.seq)
            return (b"\0" * (1 << 16) + PAUSE + b"\0" * 300 + PAUSE
                    + b"".join(self.frame() for _ in range(n)) + ok)
        if cue == "long_line":
            return LONG_LINE + b"".join(self.frame() for _ in range(n)) + ok
        if cue == "other_board":
            first = b"".join(self.frame() for _ in range(n // 2))
            self.hijacked, self.seq = True, 0
            rest = b"".join(self.frame() for _ in range(n - n // 2))
            return first + self.hello() + rest + ok
        if self.misbehaviour == "lagging" and self.samples_asked >= self.at:
            frames = [self.frame() for _ in range(n)]
            out = self.held + b"".join(frames[:-1]) + ok
            self.held = frames[-1]
            return out
        frames = [self.frame() for _ in range(n)]
        answer = b"".join(frames) + ok
        if cue == "replay":
            out = self.last_answer + answer
        elif cue == "early_ok":
            out = b"".join(frames[:-1]) + ok + frames[-1]
        elif cue == "lost_ok":
            out = b"".join(frames)
        elif cue == "dup_ok":
            self.ok_due = ok + PAUSE
            out = answer
        elif cue == "spoof_ok":
            out = b"".join(frames[:n // 2]) + ok + PAUSE + b"".join(frames[n // 2:]) + ok
        elif cue == "extra_frame":
            out = b"".join(frames) + self.frame() + ok
        elif cue == "restart_after_ok":  # in the same write as the answer: one read
            self.stretch_mm, self.presses, self.trial, self.seq = "0", [], 0, 0
            self.greeted = True
            out = answer + self.hello()
        else:
            out = answer
        self.last_answer = answer
        return out

    def received(self, data: bytes) -> bytes:
        self._inbox += data
        out = b""
        while b"\n" in self._inbox:
            line, self._inbox = self._inbox.split(b"\n", 1)
            out += self.handle(line.strip())
        return self.ending(out)

    def ending(self, out: bytes) -> bytes:
        """``out`` with the board's line endings (CR only, on cue)."""
        return out.replace(b"\n", b"\r") if self.cr_only else out

    def stream_next(self) -> bytes:
        """The next streamed frame (after another board's greeting, on cue)."""
        self.streamed += 1
        cue = self.misbehaviour if self.streamed == self.at else None
        greeting = b""
        if cue == "stream_other_board":
            self.hijacked, self.seq = True, 0
            greeting = self.hello()
        self.junk_due = self.junk_due or cue == "stream_junk"
        self.cr_only = self.cr_only or cue == "stream_cr_only"
        if self.junk_due:
            return self.ending(b"~~ not a frame ~~\n")
        self.sent.append((self.seq, self.counts(self.hijacked)))
        if cue == "stream_time_back":
            self.time_back.append(self.seq)
            return self.ending(greeting + time_fallen(self.frame()))
        return self.ending(greeting + self.frame())

    def wild(self) -> tuple[bytes, float]:
        """What a board gone wild sends next, and the pause after it."""
        if self.misbehaviour == "trickle":
            return b"~", 0.1
        return b"".join(self.frame() for _ in range(20)), 0.0


class Served:
    """A :class:`HostileBoard` on a pty or a loopback socket, in a thread."""

    def __init__(self, board: HostileBoard, transport: str = "pty") -> None:
        self.board = board
        self._stop = threading.Event()
        if transport == "pty":
            self._master, slave = os.openpty()
            tty.setraw(slave)
            self.port = os.ttyname(slave)
            self._slave = slave
            self._thread = threading.Thread(target=self._serve_pty, daemon=True)
        else:
            self._listener = socket.create_server(("127.0.0.1", 0))
            self.port = f"socket://127.0.0.1:{self._listener.getsockname()[1]}"
            self._thread = threading.Thread(target=self._serve_socket, daemon=True)
        self._thread.start()

    def _pump(self, read, write, readable) -> None:
        pending = b""
        held_until = 0.0  # a PAUSE in what the board sends: nothing goes out before this
        next_frame = time.monotonic()
        while not self._stop.is_set():
            if self.board.gone_wild and not pending:
                pending, pause = self.board.wild()
                if pause:
                    time.sleep(pause)
            now = time.monotonic()
            if self.board.streaming and not self.board.gone_wild and now >= next_frame:
                pending += self.board.stream_next()
                next_frame = max(next_frame + 0.012, now)
            wait = max(0.0, min(0.05, next_frame - now)) if self.board.streaming else 0.05
            paused = time.monotonic() < held_until
            if paused:
                wait = min(wait, held_until - time.monotonic())
            ready_r, ready_w, _ = select.select(
                [readable], [readable] if pending and not paused else [], [], max(0.0, wait))
            if ready_r:
                data = read()
                if data is None:
                    return
                pending += self.board.received(data)
            if ready_w and pending:
                if pending.startswith(PAUSE):
                    pending = pending[len(PAUSE):]
                    held_until = time.monotonic() + PAUSE_S
                    continue
                cut = pending.find(PAUSE)
                try:
                    sent = write(pending if cut < 0 else pending[:cut])
                except (BlockingIOError, InterruptedError):
                    sent = 0
                except OSError:
                    return
                pending = pending[sent:]

    def _serve_pty(self) -> None:
        os.set_blocking(self._master, False)

        def read():
            try:
                return os.read(self._master, 4096)
            except BlockingIOError:
                return b""
            except OSError:
                return b""  # no reader on the slave side just now (between opens)

        self._pump(read, lambda data: os.write(self._master, data), self._master)

    def _serve_socket(self) -> None:
        self._listener.settimeout(0.1)
        while not self._stop.is_set():
            try:
                conn, _ = self._listener.accept()
            except TimeoutError:
                continue
            conn.setblocking(False)

            def read(conn=conn):
                try:
                    data = conn.recv(4096)
                except BlockingIOError:
                    return b""
                except OSError:
                    return None
                return data if data else None

            with conn:
                self._pump(read, conn.send, conn)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        if hasattr(self, "_master"):
            os.close(self._master)
            os.close(self._slave)
        else:
            self._listener.close()

    def __enter__(self) -> Served:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
