"""The host's serial link: pyserial underneath, :class:`HostProtocol` on top.

Opens any port name pyserial knows (``/dev/ttyACM0``, a pty path, or a URL
such as ``socket://127.0.0.1:5000``). It only moves bytes, keeps deadlines
and reopens; which frame answers which request is decided by the sans-I/O
:class:`~eskin.device.host.HostProtocol`. Every wait has a deadline that
only the request's own progress extends (a frame it is owed, its reply), so
a board that trickles junk or floods frames without answering ends in an
error naming the port, never a hang; and nothing the board sends is kept
beyond one request's frames and a bounded sample of its junk.
"""

from __future__ import annotations

import io
import select
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np
import serial
from serial.tools import list_ports

from eskin.device.host import (
    Answered,
    Greeted,
    HostEvent,
    HostProtocol,
    Junk,
    OtherBoard,
    OtherSkin,
    Refused,
    Restarted,
    SampleComplete,
    SampleFrame,
    SampleIncomplete,
    StreamFrame,
    StreamGap,
    TimeJumped,
    Violation,
)
from eskin.device.protocol import UNSET_ID, Frame, Hello, ParseError
from eskin.errors import EskinError

BAUD = 115200
READ_CHUNK = 4096          # bytes per read: what a flood can put in memory at once
POLL_S = 0.05              # longest a read waits for a first byte: how often deadlines are seen
MAX_EVIDENCE_LINES = 64    # rejected lines kept per attempt (the rest only counted)
STREAM_BACKLOG = 4096      # stream events kept while a command is answered (~50 s of frames)
# Longest silence within a SAMPLE's answer, once it has begun, before the host probes with
# STREAM OFF (the request left open): a board sends its frames back to back (a frame takes
# ~10 ms at 115,200 baud), so this much silence after a frame means the answer's #OK was
# lost, or the board stalled; the probe's #OK, answered in order, tells which. Without it a
# lost #OK cost the whole timeout_s and a reconnect.
ANSWER_GAP_S = 0.25


@dataclass(frozen=True)
class StreamOverflow:
    """``dropped`` stream events did not fit the backlog kept while a command was answered
    (:data:`STREAM_BACKLOG`): the oldest went."""

    dropped: int


class LinkError(EskinError, RuntimeError):
    """The board could not be reached or stopped answering."""


class BoardRefused(LinkError):
    """The board answered ``#ERR``: asking again will not help."""


class BoardReset(LinkError):
    """A ``#HELLO`` arrived mid-request, or a ``SAMPLE``'s frame count started again (its
    ``#HELLO`` lost on the line): the board restarted and forgot its state."""


class DeviceChanged(LinkError):
    """Another board answered: a session never mixes two devices."""


class SkinMismatch(DeviceChanged):
    """The board's ``#HELLO`` says another number of terminals than the skin read has."""

    def __init__(self, message: str, hello: Hello, expected: int) -> None:
        super().__init__(message)
        self.hello = hello
        self.expected = expected


class ProtocolViolation(LinkError):
    """The board answered a command out of turn; the next request is fenced."""


@dataclass
class SampleBatch:
    """What one ``SAMPLE n`` brought back: the frames credited to it as they arrived, each
    with its place in the answer (``indexes``)."""

    requested: int
    frames: list[Frame] = field(default_factory=list)
    indexes: list[int] = field(default_factory=list)
    # An index counts from the first frame that arrived, which may not have been the
    # answer's first (SampleFrame.placed): only a whole answer places them.
    unplaced: bool = False
    rejected: list[ParseError] = field(default_factory=list)
    rejected_count: int = 0
    violation: str | None = None

    def take_back(self, frame: Frame, reason: str) -> bool:
        """Take ``frame`` out of the batch (its board time jumped forward: the frame after
        it said so), keeping it as a rejected line; False if it is not in the batch."""
        for i, mine in enumerate(self.frames):
            if mine is frame:
                del self.frames[i], self.indexes[i]
                self.reject(ParseError(reason, frame.line))
                return True
        return False

    def reject(self, error: ParseError) -> None:
        """Count a rejected line; keep the first few as evidence (bounded memory)."""
        self.rejected_count += 1
        if len(self.rejected) < MAX_EVIDENCE_LINES:
            self.rejected.append(error)

    def placed(self) -> dict[int, Frame]:
        """The frames whose place in the answer is known, by place: none if the board broke
        the protocol in its answer (nothing in it is trusted), nor if no seq placed it and
        it is not whole."""
        if self.violation or (self.unplaced and self.problem):
            return {}
        return dict(zip(self.indexes, self.frames, strict=True))

    @property
    def problem(self) -> str | None:
        """Why this batch cannot be stored whole, or None if it can.

        Whole means the protocol object credited exactly the requested frames, in
        one unbroken sequence and with board time that never fell (within the answer
        or from the last frame before it), to this request. Rejected lines between
        such frames (line noise) are kept as evidence but cost nothing: a damaged
        frame always shows as a lost sequence number or a short count.
        """
        rejected = (f" ({self.rejected_count} line(s) rejected, first: "
                    f"{self.rejected[0].reason})" if self.rejected else "")
        if self.violation:
            return f"{self.violation}{rejected}"
        if len(self.frames) != self.requested:
            return f"{len(self.frames)} of {self.requested} frames arrived{rejected}"
        return None


class SerialLink:
    """A connection to one board.

    Parameters
    ----------
    port
        Device path or pyserial URL.
    timeout_s
        Longest wait for a request's next sign of progress: a frame it is owed
        or its reply. Junk and frames nobody asked for do not count as progress.
    terminals
        The readings per frame of the skin read (``skin.terminals``): a board that
        greets with another count is :class:`SkinMismatch`. None only where no skin is
        read (giving a board its id): the board's own count.
    """

    def __init__(self, port: str, *, terminals: int | None = None, baud: int = BAUD,
                 timeout_s: float = 5.0) -> None:
        self.port = port
        self.baud = baud
        self.timeout_s = timeout_s
        self.protocol = HostProtocol(terminals=terminals)
        self._pending: deque[HostEvent] = deque()
        self._bytes_at = 0.0  # when the board last sent a byte (time.monotonic)
        # Stream events that arrive while a command is answered, for stream() to yield;
        # bounded: the oldest go first, counted, and stream() reports them (StreamOverflow).
        self._backlog: deque[HostEvent] = deque(maxlen=STREAM_BACKLOG)
        self._overflowed = 0
        # Frames of answers already closed that the frame after them judged jumped forward
        # (TimeJumped): the caller takes them back from what it kept (take_jumped).
        self._jumped: list[Frame] = []
        self._serial = self._open()

    @property
    def hello(self) -> Hello | None:
        return self.protocol.hello

    def take_jumped(self) -> list[Frame]:
        """The frames of closed answers found since the last call to have jumped forward in
        board time (the protocol judged them by the frame after them)."""
        jumped, self._jumped = self._jumped, []
        return jumped

    def _open(self) -> serial.SerialBase:
        try:
            # Reads return at once with what has arrived (timeout 0); _read waits for it.
            return serial.serial_for_url(self.port, baudrate=self.baud, timeout=0,
                                         write_timeout=self.timeout_s)
        except (serial.SerialException, OSError, ValueError) as err:
            raise LinkError(f"cannot open port {self.port}: {_os_reason(err)}") from err

    def close(self) -> None:
        try:
            self._serial.close()
        except (serial.SerialException, OSError):
            pass  # a port that vanished may fail even to close

    def reopen(self, *, budget_s: float = 30.0, notify: Callable[[str], object] = print,
               first_delay_s: float = 0.05, max_delay_s: float = 2.0) -> Hello:
        """Close, then open and greet the board again, backing off between tries.

        The board that answers must be the one greeted before (same device id).
        LinkError naming the port once ``budget_s`` has passed without success;
        no try waits past the budget.
        """
        self.close()
        started = time.monotonic()
        delay, tries = first_delay_s, 0
        while True:
            tries += 1
            remaining = budget_s - (time.monotonic() - started)
            try:
                self._serial = self._open()
                hello = self.connect(timeout_s=max(0.05, min(self.timeout_s, remaining)))
            except DeviceChanged:
                self.close()
                raise
            except LinkError as err:
                self.close()
                waited = time.monotonic() - started
                if waited + delay > budget_s:
                    raise LinkError(f"lost the board on {self.port}: no answer after {tries} "
                                    f"reconnect tries in {waited:.1f} s (last: {err})") from err
                if tries == 1:  # the error names the port, once
                    notify(f"{err}; reconnecting (backing off up to {max_delay_s:g} s, for "
                           f"at most {budget_s:g} s)")
                time.sleep(delay)
                delay = min(2 * delay, max_delay_s)
                continue
            if tries > 1:
                notify(f"{self.port}: reconnected after {tries} tries "
                       f"({time.monotonic() - started:.1f} s)")
            return hello

    def __enter__(self) -> SerialLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------ bytes

    def _write(self, data: bytes, what: str) -> None:
        try:
            self._serial.write(data)
        except (serial.SerialException, OSError) as err:
            raise LinkError(f"writing {what!r} to {self.port} failed: {err}") from err

    def _read(self, wait_s: float = POLL_S) -> None:
        """Read what the board sent (at most a chunk) into the queue of pending events,
        waiting up to ``wait_s`` for a first byte if nothing has come.

        The port reads without waiting (timeout 0) and the wait is a select on it, so a
        frame is taken the moment it arrives and a burst a chunk at a time, on any port:
        ``in_waiting`` cannot size the read, as a socket's is only ever 0 or 1."""
        try:
            data = self._serial.read(READ_CHUNK)
            if not data and wait_s > 0 and self._wait_readable(wait_s):
                data = self._serial.read(READ_CHUNK)
        except (serial.SerialException, OSError, ValueError) as err:
            raise LinkError(f"reading from {self.port} failed: {err}") from err
        if data:
            self._bytes_at = time.monotonic()
            self._pending.extend(self.protocol.receive(data))

    def _wait_readable(self, wait_s: float) -> bool:
        """Wait up to ``wait_s`` for the port to have bytes; False if none came."""
        try:
            fileno = self._serial.fileno()
        except (AttributeError, io.UnsupportedOperation):
            fileno = None  # a port with no descriptor (loop://, rfc2217://): poll it
        if fileno is None:
            deadline = time.monotonic() + wait_s
            while not self._serial.in_waiting:
                if time.monotonic() > deadline:
                    return False
                time.sleep(0.002)
            return True
        return bool(select.select([fileno], [], [], wait_s)[0])

    def _drain(self) -> None:
        """Take in what the board already sent, before a request: none of it is the
        request's (it is stray, or junk, or news of a restart)."""
        try:
            waiting = self._serial.in_waiting
        except (serial.SerialException, OSError) as err:
            raise LinkError(f"{self.port} is gone: {err}") from err
        while waiting > 0:
            self._read(wait_s=0)
            waiting = max(0, waiting - READ_CHUNK)
        while self._pending:  # events left over from the last request's read count too
            event = self._pending.popleft()
            if isinstance(event, TimeJumped):
                self._jumped.append(event.frame)
            elif not self._kept_for_stream(event):
                self._raise_for_board(event, "before a request")

    def _kept_for_stream(self, event: HostEvent) -> bool:
        """A stream event met while answering a command waits for stream()."""
        if isinstance(event, StreamFrame | StreamGap):
            if len(self._backlog) == self._backlog.maxlen:
                self._overflowed += 1
            self._backlog.append(event)
            return True
        return False

    def _exchange(self, request: bytes, what: str, on_event: Callable[[HostEvent], bool | None],
                  timeout_s: float | None = None, *, probe: bool = False) -> None:
        """Send a request and feed events to ``on_event`` until it returns True.

        ``on_event`` returns None for an event that is not progress; anything else
        that is not True is progress (the deadline moves). An ``#ERR`` for the
        request is BoardRefused. ``probe`` (a SAMPLE): once its answer has begun, a
        silence of :data:`ANSWER_GAP_S` (at most half the timeout) sends the protocol's
        probe, once, so that a lost ``#OK`` costs that, not the timeout. The deadline
        passing, the request is abandoned and LinkError names the port."""
        timeout = self.timeout_s if timeout_s is None else timeout_s
        gap = min(ANSWER_GAP_S, timeout / 2)
        self._write(request, what)
        progressed = time.monotonic()
        deadline = progressed + timeout
        junk = _JunkSeen()
        while True:
            # Silence is no byte at all: a long line still arriving (junk being dropped
            # whole) is the board talking, not an #OK lost; and bytes waiting unread (this
            # process was not scheduled for a while) are not silence either.
            if (probe and self.protocol.answer_begun and not self._pending
                    and time.monotonic() - max(progressed, self._bytes_at) > gap
                    and not self._wait_readable(0)):
                probe = False
                self._write(self.protocol.send_probe(), "STREAM OFF")
            if not self._pending:
                self._read(min(POLL_S, gap) if probe else POLL_S)
            # One event at a time: what follows the answer in the same read (a restart,
            # say) stays queued for the next request to see.
            while self._pending:
                event = self._pending.popleft()
                if isinstance(event, Refused):  # #ERR: asking again will not help
                    said = event.reply.line.decode("ascii", "backslashreplace").strip()
                    raise BoardRefused(f"the board on {self.port} refused {what!r}: it "
                                       f"said {said!r}")
                if self._kept_for_stream(event):
                    continue
                junk.note(event)
                result = on_event(event)
                if isinstance(event, TimeJumped) and result is None:
                    self._jumped.append(event.frame)  # not the open request's
                if result is True:
                    return
                if result is not None:
                    progressed = time.monotonic()
                    deadline = progressed + timeout
            if time.monotonic() > deadline:
                self.protocol.abandon()
                raise LinkError(f"board on {self.port} did not answer {what!r} within "
                                f"{timeout:.2g} s{junk.says(self.protocol)}")

    def _raise_for_board(self, event: HostEvent, during: str) -> None:
        if isinstance(event, OtherSkin):
            count = event.hello.terminals
            raise SkinMismatch(
                f"the board on {self.port} has {count} terminals (its #HELLO says "
                f"terminals={count}), not the {event.expected} of the skin read",
                event.hello, event.expected)
        if isinstance(event, OtherBoard):
            raise DeviceChanged(
                f"another board answered on {self.port} {during} (id {event.hello.device_id}, "
                f"expected {event.expected}); stopping so that one session never mixes two "
                "devices")
        if isinstance(event, Restarted):
            raise BoardReset(f"board on {self.port} restarted {during}")

    # ------------------------------------------------------------ requests

    def connect(self, *, timeout_s: float | None = None) -> Hello:
        """Discard stale bytes, greet the board and keep its #HELLO.

        A board other than the one this link greeted before is DeviceChanged.
        """
        try:
            self._serial.reset_input_buffer()
        except (serial.SerialException, OSError) as err:
            raise LinkError(f"{self.port} is gone: {err}") from err
        self.protocol.reset_link()
        self._pending.clear()
        greeted: list[Hello] = []

        def on_event(event: HostEvent) -> bool | None:
            if isinstance(event, OtherSkin | OtherBoard):
                self._raise_for_board(event, "after reconnecting")
            if isinstance(event, Greeted):
                greeted.append(event.hello)
                return True
            if isinstance(event, Violation):
                raise LinkError(f"board on {self.port} did not greet: {event.reason}")
            return None

        self._exchange(self.protocol.send_greeting(), "HELLO", on_event, timeout_s)
        return greeted[0]

    def fence(self) -> None:
        """``STREAM OFF`` and its ``#OK``: the board has sent everything it owed."""
        def on_event(event: HostEvent) -> bool | None:
            self._raise_for_board(event, "during STREAM OFF")
            if isinstance(event, Answered):
                return True
            return None

        self._exchange(self.protocol.send_fence(), "STREAM OFF", on_event)

    def quiet(self) -> None:
        """Take in what the board already sent and, if it may still owe frames (a violation,
        a short answer, an ``#OK`` out of turn), fence: after this the board sends nothing
        unasked. A request does this first; so must whatever acts on the board outside the
        protocol (the emulated rig's weights and replays): a scan the board still owed an
        earlier answer would otherwise read what was meant for the next one."""
        self._drain()
        if self.protocol.needs_fence:
            self.fence()

    def command(self, command: str) -> None:
        """Send a command and wait for its #OK; #ERR becomes BoardRefused, a #HELLO
        (the board restarted) BoardReset, another board DeviceChanged.

        Frames arriving meanwhile (a board left streaming) are stray and dropped:
        they belong to no requested condition.
        """
        self.quiet()

        def on_event(event: HostEvent) -> bool | None:
            self._raise_for_board(event, f"during {command!r}")
            if isinstance(event, Answered):
                return True
            if isinstance(event, Violation):
                raise ProtocolViolation(f"board on {self.port} broke protocol during "
                                        f"{command!r}: {event.reason}")
            return None

        self._exchange(self.protocol.send_command(command), command, on_event)

    def start_stream(self) -> None:
        """``STREAM ON`` and its ``#OK``: the board sends frames until stopped."""
        self.command("STREAM ON")

    def stop_stream(self) -> None:
        """``STREAM OFF`` (the fence): nothing more is sent."""
        self.fence()
        self._backlog.clear()

    def stream(self, *, timeout_s: float | None = None) -> Iterator[list[HostEvent]]:
        """The live stream, as the events each read brought (so a consumer can handle
        what has arrived at once): :class:`StreamFrame`, :class:`StreamGap` (frames lost)
        and :class:`Junk` (a line that failed its check), and :class:`StreamOverflow` for
        stream events dropped while a long command was answered. LinkError when no valid
        frame arrives for ``timeout_s`` (default: the link's; junk is reported, but it is
        not a stream), BoardReset or DeviceChanged as for a request."""
        timeout = self.timeout_s if timeout_s is None else timeout_s
        deadline = time.monotonic() + timeout
        junk = _JunkSeen()
        while True:
            arrived: list = [StreamOverflow(self._overflowed)] if self._overflowed else []
            arrived += self._backlog
            self._backlog.clear()
            self._overflowed = 0
            if not self._pending:
                self._read()
            while self._pending:
                event = self._pending.popleft()
                if isinstance(event, OtherBoard | OtherSkin | Restarted) and arrived:
                    # Our board's frames that came in the same read as another board's
                    # #HELLO (or our own restart) are handed over first; the next pass
                    # raises.
                    self._pending.appendleft(event)
                    break
                self._raise_for_board(event, "while streaming")
                if isinstance(event, StreamFrame | StreamGap | Junk):
                    arrived.append(event)
            progress = any(isinstance(event, StreamFrame) for event in arrived)
            for event in arrived:
                junk.note(event)
            if arrived:
                yield arrived
            if progress:  # after the yield: the consumer's time is not the board's silence
                deadline = time.monotonic() + timeout
                junk = _JunkSeen()
            elif time.monotonic() > deadline:
                raise LinkError(f"board on {self.port} sent no valid frame for "
                                f"{timeout:.2g} s while streaming{junk.says(self.protocol)}")

    def sample(self, batch: SampleBatch) -> SampleBatch:
        """Request ``batch.requested`` frames and collect into ``batch`` those the
        protocol credits to this request, with their places in the answer, and the
        rejected lines as evidence. Filled as they arrive, so whatever came before an
        error or a Ctrl-C is in ``batch``; a protocol violation ends the request with
        ``batch.violation`` set."""
        n = batch.requested
        self.quiet()

        def on_event(event: HostEvent) -> bool | None:
            self._raise_for_board(event, f"during SAMPLE {n} ({len(batch.frames)} frame(s) "
                                  "had arrived)")
            if isinstance(event, SampleFrame):
                batch.frames.append(event.frame)
                batch.indexes.append(event.index)
                batch.unplaced = batch.unplaced or not event.placed
                return False
            if isinstance(event, Junk):
                batch.reject(event.error)
                return None
            if isinstance(event, TimeJumped):
                taken = batch.take_back(event.frame, (
                    f"board time jumped forward at seq {event.frame.seq} ({event.frame.t_ms}):"
                    " the next frame fell below it, not below the one before it"))
                return False if taken else None
            if isinstance(event, SampleComplete | SampleIncomplete):
                return True
            if isinstance(event, Violation):
                batch.violation = event.reason
                if event.restart:  # nothing in the batch is kept, and the board is told
                    raise BoardReset(f"board on {self.port} during SAMPLE {n}: "  # again
                                     f"{event.reason}")
                return True
            return None

        self._exchange(self.protocol.send_sample(n), f"SAMPLE {n}", on_event, probe=True)
        return batch


class _JunkSeen:
    """The lines a wait rejected, for the error when it times out: how many, the last."""

    def __init__(self) -> None:
        self.count = 0
        self.last: ParseError | None = None

    def note(self, event: object) -> None:
        if isinstance(event, Junk):
            self.count += 1
            self.last = event.error

    def says(self, protocol: HostProtocol) -> str:
        """`` (n line(s) rejected, last: why)``, and the line-ending hint if the board's
        bytes give one; empty if there is neither."""
        out = (f" ({self.count} line(s) rejected, last: {self.last.reason})"
               if self.last is not None else "")
        hint = protocol.line_ending_hint
        if hint and (self.last is None or hint not in self.last.reason):
            out += f"; {hint}"
        return out


def _os_reason(err: BaseException) -> str:
    """What the OS said under a pyserial error, whose own text names the port again."""
    for cause in (err.__cause__, err.__context__):
        if isinstance(cause, OSError) and cause.strerror:
            return cause.strerror
    return str(err)


def digits_lost(frames: list[Frame], max_jump_counts: float) -> tuple[int, str] | None:
    """The frame among a condition's ``frames`` (by index) with a reading that lost
    digits, and why; None if none did.

    CRC-8 passes 1 in 256 damaged lines that keep a frame's shape, and the only
    damage that keeps it is digits lost from one field (a lost comma leaves a
    field short). A lost digit in ``seq`` shows as a gap, in ``t_ms`` as time
    running backwards (``SampleBatch.problem``); in a count, as a reading with
    fewer digits than its terminal's median over the condition and far from it:
    further than ``max_jump_counts`` and than 10 robust standard deviations of
    that terminal in the condition, so a noisy skin is not mistaken for damage.
    """
    if len(frames) < 3:
        return None
    counts = np.array([f.counts for f in frames], dtype=float)
    median = np.median(counts, axis=0)
    sigma = 1.4826 * np.median(np.abs(counts - median), axis=0)
    limit = np.maximum(max_jump_counts, 10 * sigma)

    def digits(values: np.ndarray) -> np.ndarray:
        return np.floor(np.log10(np.maximum(np.floor(values), 1))) + 1

    jump = np.where(digits(counts) < digits(median), np.abs(counts - median), 0.0)
    jump[jump <= limit] = 0.0
    if not jump.any():
        return None
    sample, channel = np.unravel_index(int(np.argmax(jump)), jump.shape)
    return int(sample), (
        f"sample {sample} (seq {frames[sample].seq}) reads "
        f"{counts[sample, channel]:g} on terminal {channel + 1}, whose median is "
        f"{median[channel]:g}: fewer digits and {jump[sample, channel]:g} counts away "
        f"(limit {limit[channel]:g}: acquire.max_jump_counts or 10 sigma): digits lost in a "
        "frame whose CRC-8 matched by chance")


def set_device_id(port: str, device_id: str, *, timeout_s: float = 5.0) -> Hello:
    """Give the board on ``port`` its id, once (``ID <id>``, kept in its EEPROM); returns
    its greeting after. A board that has an id, or refuses this one, is an error."""
    with SerialLink(port, timeout_s=timeout_s) as link:
        hello = link.connect()
        if hello.device_id != UNSET_ID:
            raise LinkError(f"the board on {port} already has the id {hello.device_id!r}: "
                            "an id is set once")
        link.command(f"ID {device_id}")
    with SerialLink(port, timeout_s=timeout_s) as link:  # a new link: this board is new to it
        return link.connect()


def list_serial_ports() -> list[tuple[str, str, str]]:
    """(device, description, hardware id) of every serial port pyserial sees."""
    return [(p.device, p.description, p.hwid) for p in list_ports.comports()]
