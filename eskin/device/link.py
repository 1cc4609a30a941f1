"""The host's serial link: pyserial underneath, the sans-I/O parser on top.

Opens any port name pyserial knows (``/dev/ttyACM0``, a pty path, or a URL
such as ``socket://127.0.0.1:5000``) and turns requests into events. A board
that falls silent longer than the timeout is an error naming the port,
never a hang.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import serial
from serial.tools import list_ports

from eskin.device.protocol import Event, Frame, FrameParser, Hello, ParseError, Reply, SequenceGap

BAUD = 115200


class LinkError(RuntimeError):
    """The board could not be reached or stopped answering."""


class BoardRefused(LinkError):
    """The board answered ``#ERR``: asking again will not help."""


class BoardReset(LinkError):
    """A ``#HELLO`` arrived mid-request: the board restarted and forgot its state."""


class DeviceChanged(LinkError):
    """Another board answered on the port after a reconnect."""


@dataclass
class SampleBatch:
    """What one ``SAMPLE n`` brought back."""

    requested: int
    frames: list[Frame] = field(default_factory=list)
    rejected: list[ParseError] = field(default_factory=list)
    gaps: list[SequenceGap] = field(default_factory=list)

    @property
    def problem(self) -> str | None:
        """Why this batch cannot be stored whole, or None if it can.

        Whole means every requested frame, verified, in one unbroken sequence.
        Rejected lines between such frames (line noise) are kept as evidence but
        cost nothing: a damaged frame always shows as a gap or a short count.
        """
        rejected = (f" ({len(self.rejected)} line(s) rejected, first: "
                    f"{self.rejected[0].reason})" if self.rejected else "")
        if self.gaps:
            return (f"frames lost: expected seq {self.gaps[0].expected}, "
                    f"got {self.gaps[0].got}{rejected}")
        if len(self.frames) != self.requested:
            return f"{len(self.frames)} of {self.requested} frames arrived{rejected}"
        seqs = [f.seq for f in self.frames]
        if any(b != a + 1 for a, b in zip(seqs, seqs[1:], strict=False)):
            return f"frame sequence is not consecutive{rejected}"
        for a, b in zip(self.frames, self.frames[1:], strict=False):
            # Board time only grows (but for the 32-bit wrap after 49 days): a t_ms that
            # falls is a damaged frame whose CRC-8 matched by chance.
            if b.t_ms < a.t_ms and a.t_ms - b.t_ms < 2**31:
                return f"board time went backwards at seq {b.seq} ({a.t_ms} then {b.t_ms})"
        return None


class SerialLink:
    """A connection to one board.

    Parameters
    ----------
    port
        Device path or pyserial URL.
    timeout_s
        Longest silence tolerated while waiting for an answer.
    """

    def __init__(self, port: str, *, baud: int = BAUD, timeout_s: float = 5.0) -> None:
        self.port = port
        self.baud = baud
        self.timeout_s = timeout_s
        self._serial = self._open()
        self.parser = FrameParser()
        self._pending: list[Event] = []
        self.hello: Hello | None = None

    def _open(self) -> serial.SerialBase:
        try:
            return serial.serial_for_url(self.port, baudrate=self.baud, timeout=0.05,
                                         write_timeout=self.timeout_s)
        except (serial.SerialException, OSError, ValueError) as err:
            raise LinkError(f"cannot open port {self.port}: {err}") from err

    def close(self) -> None:
        try:
            self._serial.close()
        except (serial.SerialException, OSError):
            pass  # a port that vanished may fail even to close

    def reopen(self, *, budget_s: float = 30.0, notify: Callable[[str], object] = print,
               first_delay_s: float = 0.05, max_delay_s: float = 2.0) -> Hello:
        """Close, then open and greet the board again, backing off between tries.

        The board that answers must be the one greeted before (same device id).
        LinkError naming the port once ``budget_s`` has passed without success.
        """
        expected = self.hello.device_id if self.hello else None
        self.close()
        started = time.monotonic()
        delay, tries = first_delay_s, 0
        while True:
            tries += 1
            try:
                self._serial = self._open()
                hello = self.connect()
            except DeviceChanged:
                raise
            except LinkError as err:
                self.close()
                waited = time.monotonic() - started
                if waited + delay > budget_s:
                    raise LinkError(f"lost the board on {self.port}: no answer after {tries} "
                                    f"reconnect tries in {waited:.1f} s (last: {err})") from err
                if tries == 1:
                    notify(f"{self.port}: {err}; reconnecting (backing off up to "
                           f"{max_delay_s:g} s, for at most {budget_s:g} s)")
                time.sleep(delay)
                delay = min(2 * delay, max_delay_s)
                continue
            if expected is not None and hello.device_id != expected:
                self.close()
                raise DeviceChanged(f"another board answered on {self.port} after reconnecting "
                                    f"(id {hello.device_id}, expected {expected}); stopping so "
                                    "that one session never mixes two devices")
            if tries > 1:
                notify(f"{self.port}: reconnected after {tries} tries "
                       f"({time.monotonic() - started:.1f} s)")
            return hello

    def __enter__(self) -> SerialLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------ bytes

    def send(self, command: str) -> None:
        try:
            self._serial.write(command.encode("ascii") + b"\n")
        except (serial.SerialException, OSError) as err:
            raise LinkError(f"writing {command!r} to {self.port} failed: {err}") from err

    def next_event(self) -> Event:
        """The next event from the board; LinkError after ``timeout_s`` of silence."""
        deadline = time.monotonic() + self.timeout_s
        while not self._pending:
            try:
                data = self._serial.read(max(1, self._serial.in_waiting))
            except (serial.SerialException, OSError) as err:
                raise LinkError(f"reading from {self.port} failed: {err}") from err
            if data:
                self._pending.extend(self.parser.feed(data))
                deadline = time.monotonic() + self.timeout_s
            elif time.monotonic() > deadline:
                raise LinkError(f"board on {self.port} silent for {self.timeout_s:g} s")
        return self._pending.pop(0)

    # ------------------------------------------------------------ requests

    def connect(self) -> Hello:
        """Discard stale bytes, greet the board and keep its #HELLO.

        ``STREAM OFF`` follows the greeting as a fence: every ``#HELLO`` before
        its ``#OK`` belongs to this connection (the board's power-up greeting may
        arrive after the stale bytes were discarded), so one that comes later
        can only mean the board restarted.
        """
        try:
            self._serial.reset_input_buffer()
        except (serial.SerialException, OSError) as err:
            raise LinkError(f"{self.port} is gone: {err}") from err
        self._pending.clear()
        self.parser = FrameParser()
        self.send("HELLO")
        self.send("STREAM OFF")
        hello = None
        while True:
            event = self.next_event()
            if isinstance(event, Hello):
                hello = event
            elif isinstance(event, Reply) and event.command.upper() == "STREAM" and hello:
                self.hello = hello
                return hello

    def command(self, command: str) -> Reply:
        """Send a command and wait for its #OK; #ERR becomes BoardRefused, a #HELLO
        (the board restarted) BoardReset.

        Frames arriving meanwhile (a board left streaming) are dropped: they
        belong to no requested condition.
        """
        self.send(command)
        name = command.split()[0].upper()
        while True:
            event = self.next_event()
            if isinstance(event, Hello):
                raise BoardReset(f"board on {self.port} restarted during {command!r}")
            if isinstance(event, Reply) and event.command.upper() == name:
                if not event.ok:
                    raise BoardRefused(f"board on {self.port} refused {command!r}: "
                                       f"{event.details}")
                return event

    def sample(self, batch: SampleBatch) -> SampleBatch:
        """Request ``batch.requested`` frames and collect into ``batch`` all that come back,
        good and bad, until #OK SAMPLE. Filled as they arrive, so whatever came before an
        error or a Ctrl-C is in ``batch``."""
        n = batch.requested
        self.parser.reset_sequence()
        self.send(f"SAMPLE {n}")
        while True:
            event = self.next_event()
            if isinstance(event, Hello):
                raise BoardReset(f"board on {self.port} restarted during SAMPLE {n} "
                                 f"({len(batch.frames)} frame(s) had arrived)")
            if isinstance(event, Frame):
                batch.frames.append(event)
            elif isinstance(event, ParseError):
                batch.rejected.append(event)
            elif isinstance(event, SequenceGap):
                batch.gaps.append(event)
            elif isinstance(event, Reply) and event.command.upper() == "SAMPLE":
                if not event.ok:
                    raise BoardRefused(f"board on {self.port} refused SAMPLE {n}: "
                                       f"{event.details}")
                return batch


def jump_problem(batch: SampleBatch, max_jump_counts: float) -> str | None:
    """Why a whole batch still cannot be trusted: a reading that lost digits.

    CRC-8 passes 1 in 256 damaged lines that keep a frame's shape, and the only
    damage that keeps it is digits lost from one field (a lost comma leaves a
    field short). A lost digit in ``seq`` shows as a gap, in ``t_ms`` as time
    running backwards (``SampleBatch.problem``); in a count, as a reading with
    fewer digits than its terminal's median over the condition and far from it:
    further than ``max_jump_counts`` and than 10 robust standard deviations of
    that terminal in the condition, so a noisy skin is not mistaken for damage.
    """
    if len(batch.frames) < 3:
        return None
    counts = np.array([f.counts for f in batch.frames], dtype=float)
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
    return (f"sample {sample} (seq {batch.frames[sample].seq}) reads "
            f"{counts[sample, channel]:g} on terminal {channel + 1}, whose median is "
            f"{median[channel]:g}: fewer digits and {jump[sample, channel]:g} counts away "
            f"(limit {limit[channel]:g}: acquire.max_jump_counts or 10 sigma): digits lost in a "
            "frame whose CRC-8 matched by chance")


def list_serial_ports() -> list[tuple[str, str, str]]:
    """(device, description, hardware id) of every serial port pyserial sees."""
    return [(p.device, p.description, p.hwid) for p in list_ports.comports()]
