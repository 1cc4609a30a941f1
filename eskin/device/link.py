"""The host's serial link: pyserial underneath, the sans-I/O parser on top.

Opens any port name pyserial knows (``/dev/ttyACM0``, a pty path, or a URL
such as ``socket://127.0.0.1:5000``) and turns requests into events. A board
that falls silent longer than the timeout is an error naming the port,
never a hang.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import serial
from serial.tools import list_ports

from eskin.device.protocol import Event, Frame, FrameParser, Hello, ParseError, Reply, SequenceGap

BAUD = 115200


class LinkError(RuntimeError):
    """The board could not be reached or stopped answering."""


@dataclass
class SampleBatch:
    """What one ``SAMPLE n`` brought back."""

    requested: int
    frames: list[Frame] = field(default_factory=list)
    rejected: list[ParseError] = field(default_factory=list)
    gaps: list[SequenceGap] = field(default_factory=list)

    @property
    def problem(self) -> str | None:
        """Why this batch cannot be stored whole, or None if it can."""
        if self.rejected:
            return f"{len(self.rejected)} line(s) rejected: {self.rejected[0].reason}"
        if self.gaps:
            return f"frames lost: expected seq {self.gaps[0].expected}, got {self.gaps[0].got}"
        if len(self.frames) != self.requested:
            return f"{len(self.frames)} of {self.requested} frames arrived"
        seqs = [f.seq for f in self.frames]
        if any(b != a + 1 for a, b in zip(seqs, seqs[1:], strict=False)):
            return "frame sequence is not consecutive"
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
        self.timeout_s = timeout_s
        try:
            self._serial = serial.serial_for_url(port, baudrate=baud, timeout=0.05,
                                                 write_timeout=timeout_s)
        except (serial.SerialException, OSError, ValueError) as err:
            raise LinkError(f"cannot open port {port}: {err}") from err
        self.parser = FrameParser()
        self._pending: list[Event] = []
        self.hello: Hello | None = None

    def close(self) -> None:
        self._serial.close()

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
        """Discard stale bytes, greet the board and keep its #HELLO."""
        self._serial.reset_input_buffer()
        self._pending.clear()
        self.parser = FrameParser()
        self.send("HELLO")
        while True:
            event = self.next_event()
            if isinstance(event, Hello):
                self.hello = event
                return event

    def command(self, command: str) -> Reply:
        """Send a command and wait for its #OK; #ERR becomes a LinkError.

        Frames arriving meanwhile (a board left streaming) are dropped: they
        belong to no requested condition.
        """
        self.send(command)
        name = command.split()[0].upper()
        while True:
            event = self.next_event()
            if isinstance(event, Reply) and event.command.upper() == name:
                if not event.ok:
                    raise LinkError(f"board on {self.port} refused {command!r}: {event.details}")
                return event

    def sample(self, n: int) -> SampleBatch:
        """Request n frames; return all that came back, good and bad, until #OK SAMPLE."""
        self.parser.reset_sequence()
        self.send(f"SAMPLE {n}")
        batch = SampleBatch(n)
        while True:
            event = self.next_event()
            if isinstance(event, Frame):
                batch.frames.append(event)
            elif isinstance(event, ParseError):
                batch.rejected.append(event)
            elif isinstance(event, SequenceGap):
                batch.gaps.append(event)
            elif isinstance(event, Reply) and event.command.upper() == "SAMPLE":
                if not event.ok:
                    raise LinkError(f"board on {self.port} refused SAMPLE {n}: {event.details}")
                return batch


def list_serial_ports() -> list[tuple[str, str, str]]:
    """(device, description, hardware id) of every serial port pyserial sees."""
    return [(p.device, p.description, p.hwid) for p in list_ports.comports()]
