"""Live: a scene's stack (:mod:`eskin.deploy.stack`) on a board's stream, frame by frame.

:func:`live_estimates` runs a stack on a :class:`~eskin.device.link.SerialLink` that
streams (``STREAM ON``): a tare first (frames with nothing pressed, whose offset from the
training data's rest reading is taken off every frame after), then one estimate per frame,
carrying the board's ``seq`` and ``t_ms``; a lost frame or a damaged line is reported
where it happened and never predicted. :class:`LineBroadcast` hands the estimates to other
programs as JSON lines on 127.0.0.1.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from eskin.deploy.stack import ExportedStack, SkinStack

TARE_FRAMES = 100  # about 1.2 s of the stream at the board's 12 ms frame period


@dataclass
class Tare:
    """A live board's offset from the training rest reading, taken with nothing pressed,
    and taken off every frame after. ``drift`` is how far, in counts (the largest channel),
    the untouched reading has moved since (a running average over ``drift_frames`` of the
    frames without contact; a stretch moves it too). Without a tare (:meth:`none`) there
    is nothing to measure drift or change from: both are None."""

    offset: np.ndarray
    reading: np.ndarray | None
    drift_frames: int = 200
    _recent: np.ndarray = None  # type: ignore[assignment]  # starts at the tare's reading

    @classmethod
    def take(cls, frames: np.ndarray, rest: np.ndarray | None) -> Tare:
        reading = np.asarray(frames, dtype=np.float64).mean(axis=0)
        offset = reading - rest if rest is not None else np.zeros_like(reading)
        return cls(offset, reading, _recent=reading.copy())

    @classmethod
    def none(cls, channels: int) -> Tare:
        return cls(np.zeros(channels), None)

    def apply(self, counts: np.ndarray) -> np.ndarray:
        return np.asarray(counts, dtype=np.float64) - self.offset

    def note_rest(self, counts: np.ndarray) -> None:
        if self.reading is None:
            return
        weight = 1.0 / self.drift_frames
        self._recent = (1 - weight) * self._recent + weight * np.asarray(counts, np.float64)

    @property
    def drift(self) -> float | None:
        if self.reading is None:
            return None
        return round(float(np.max(np.abs(self._recent - self.reading))), 3)


def _number(value: Any) -> Any:
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (float, np.floating)):
        return None if math.isnan(value) else round(float(value), 6)
    if isinstance(value, (np.integer,)):
        return int(value)
    return value


def live_estimates(stack: SkinStack | ExportedStack, batches: Iterable[list], *,
                   tare_frames: int = TARE_FRAMES, with_change: bool = False,
                   notify: Callable[[str], object] = lambda message: None
                   ) -> Iterator[dict[str, Any]]:
    """One record per stream event, in order: an estimate per frame (``seq``, ``t_ms``,
    the stack's columns and the drift since the tare), ``{"gap": ...}`` for lost frames,
    ``{"rejected": ...}`` for a line that failed its check. The first ``tare_frames``
    frames are the tare (nothing may be pressed), reported once as ``{"tare": ...}``
    (``tare_frames=0``: no tare). ``batches`` are the events as they arrived: a batch's
    frames are predicted together, as a scikit-learn call costs milliseconds whatever
    its rows, so the stack keeps up with the board. ``with_change``: each estimate also
    carries ``change_counts``, every channel's change since the tare (the live view's
    bars)."""
    from eskin.device.host import Junk, StreamFrame, StreamGap
    from eskin.device.link import StreamOverflow

    taring: list[np.ndarray] = []
    tare = Tare.none(stack.skin.terminals) if tare_frames <= 0 else None
    for batch in batches:
        records: list[dict[str, Any] | None] = []
        pending: list[tuple[int, Any]] = []  # (index in records, frame) to predict
        for event in batch:
            if isinstance(event, StreamGap):
                records.append({"gap": {"expected": event.expected, "got": event.got,
                                        "lost": (event.got - event.expected) % 2**32}})
            elif isinstance(event, Junk):
                records.append({"rejected": event.error.reason})
            elif isinstance(event, StreamOverflow):
                records.append({"overflow": {"dropped": event.dropped}})
            elif isinstance(event, StreamFrame):
                counts = np.asarray(event.frame.counts, dtype=np.float64)
                if tare is not None:
                    pending.append((len(records), event.frame))
                    records.append(None)
                    continue
                taring.append(counts)
                if len(taring) == tare_frames:
                    tare = Tare.take(np.array(taring), stack.rest)
                    notify(f"tared on {tare_frames} frames")
                    records.append({"tare": {"frames": tare_frames, "offset_counts":
                                             [round(float(v), 3) for v in tare.offset]}})
        if pending:
            counts = np.array([frame.counts for _, frame in pending], dtype=np.float64)
            estimates = stack.predict(tare.apply(counts))
            contact = estimates["contact"].to_numpy() if "contact" in estimates else None
            for row, (at, frame) in enumerate(pending):
                if contact is not None and not contact[row]:
                    tare.note_rest(counts[row])
                record = {"seq": frame.seq, "t_ms": frame.t_ms}
                record.update({name: _number(estimates[name].iloc[row])
                               for name in stack.columns})
                record["drift_counts"] = tare.drift
                if with_change:
                    record["change_counts"] = None if tare.reading is None else [
                        round(float(v), 1) for v in counts[row] - tare.reading]
                records[at] = record
        yield from records


def json_line(record: dict[str, Any]) -> str:
    return json.dumps(record, separators=(",", ":"), allow_nan=False)


def stream_events(link, *, reconnect_s: float = 30.0, timeout_s: float | None = None,
                  notify: Callable[[str], object] = print) -> Iterator:
    """The board's stream as batches of events (:meth:`SerialLink.stream`), started, and
    started again after a restart or a lost link reopened (as acquisition reopens it,
    within ``reconnect_s``). Stops the stream when closed.

    Gives up (LinkError, one line) once no valid frame has come for the stream's timeout
    plus ``reconnect_s``, however much else came: a board that streams only junk, or
    restarts before every frame, answers commands but is not streaming. Another board
    (DeviceChanged) or a refusal ends it at once: reconnecting would not help."""
    from eskin.device.host import StreamFrame
    from eskin.device.link import BoardRefused, BoardReset, DeviceChanged, LinkError

    give_up_s = (link.timeout_s if timeout_s is None else timeout_s) + reconnect_s
    link.start_stream()
    last_frame = time.monotonic()
    try:
        while True:
            try:
                for batch in link.stream(timeout_s=timeout_s):
                    if any(isinstance(event, StreamFrame) for event in batch):
                        last_frame = time.monotonic()
                    yield batch
            except (DeviceChanged, BoardRefused):
                raise
            except LinkError as err:  # BoardReset too
                silent = time.monotonic() - last_frame
                if silent > give_up_s:
                    raise LinkError(f"{err}; giving up: no valid frame for {silent:.1f} s "
                                    f"(acquire.timeout_s + reconnect_s); does the board speak "
                                    f"protocol v1 at {link.baud} baud?") from err
                if isinstance(err, BoardReset):
                    notify(f"{link.port}: the board restarted; streaming again")
                else:
                    notify(str(err))  # it names the port
                    link.reopen(budget_s=reconnect_s, notify=notify)
                link.start_stream()
    finally:
        try:
            link.stop_stream()
        except (LinkError, OSError):
            pass  # the link is gone: nothing to stop


class LineBroadcast:
    """JSON lines for other programs: a TCP server on 127.0.0.1 that sends every line to
    every connected client. Each client has a bounded backlog (``max_backlog`` bytes): one
    that does not read is dropped, and the live loop never waits for anybody."""

    def __init__(self, port: int = 0, *, max_backlog: int = 1 << 20,
                 notify: Callable[[str], object] = lambda message: None) -> None:
        import socket

        self._server = socket.create_server(("127.0.0.1", port))
        self._server.setblocking(False)
        self.port = self._server.getsockname()[1]
        self.max_backlog = max_backlog
        self.notify = notify
        self._clients: dict[Any, bytearray] = {}

    def _accept(self) -> None:
        while True:
            try:
                client, address = self._server.accept()
            except BlockingIOError:
                return
            client.setblocking(False)
            self._clients[client] = bytearray()
            self.notify(f"client {address[0]}:{address[1]} connected")

    def send(self, line: str) -> None:
        self._accept()
        data = (line + "\n").encode()
        for client, backlog in list(self._clients.items()):
            backlog += data
            try:
                sent = client.send(backlog)
                del backlog[:sent]
            except BlockingIOError:
                pass
            except OSError:  # the client went away
                self._drop(client, "disconnected")
                continue
            if len(backlog) > self.max_backlog:
                self._drop(client, f"dropped: more than {self.max_backlog} bytes unread")

    def _drop(self, client, why: str) -> None:
        self._clients.pop(client, None)
        try:
            self.notify(f"client {client.getpeername()[1]} {why}")
        except OSError:
            self.notify(f"a client {why}")
        client.close()

    def close(self) -> None:
        for client in list(self._clients):
            client.close()
        self._clients.clear()
        self._server.close()

    def __enter__(self) -> LineBroadcast:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class LiveRecorder:
    """``eskin live --record``: the stream's frames appended to the scene's raw log as a
    live session, so that a demonstration is kept as data, versioned with the scene's.

    The frames go in attempts of at most ``chunk`` frames, each one unbroken run of the
    board's sequence: a gap, a restart or a lost link ends one and the next begins after
    it, and each is closed (``E``) and flushed as it ends, so an interruption loses at
    most the frames of the attempt under way. Their conditions (``{"key": "live/<session>/
    <n>", "live": true}``) are no plan's: ingest leaves them out of the training data
    and puts them in ``data/processed/<scene>.live.parquet``. Rejected lines are kept as
    evidence, the first ``MAX_EVIDENCE_LINES`` of an attempt, as acquisition keeps them.
    """

    def __init__(self, writer, session: str, *, chunk: int = 500) -> None:
        self.writer, self.session, self.chunk = writer, session, chunk
        self.attempt: int | None = None
        self.in_attempt = self.rejected_in_attempt = self.frames = self.attempts = 0
        self.last_seq = -1

    @classmethod
    def open(cls, raw_dir, scene: str, hello, *, port: str, source: str, stack: str,
             chunk: int = 500) -> LiveRecorder:
        from datetime import UTC, datetime

        from eskin import __version__
        from eskin.acquisition.rawlog import LOG_NAME, RawLogWriter, read_log_if_any

        path = Path(raw_dir) / LOG_NAME
        contents = read_log_if_any(path)
        live = {s["session"] for s in (contents.sessions if contents else [])
                if s.get("mode") == "live"}
        session = f"live{len(live) + 1:03d}"
        header = {"session": session, "mode": "live", "scene": scene, "eskin": __version__,
                  "source": source, "port": port, "stack": stack,
                  "device": {"id": hello.device_id, "firmware": hello.firmware,
                             "terminals": hello.terminals, "adc_bits": hello.adc_bits},
                  "started_utc": datetime.now(UTC).isoformat(timespec="seconds")}
        return cls(RawLogWriter(path, header, contents), session, chunk=chunk)

    def tap(self, batches: Iterable[list]) -> Iterator[list]:
        """``batches`` as they are, each recorded first."""
        for batch in batches:
            self.record(batch)
            yield batch

    def record(self, batch: list) -> None:
        from eskin.device.host import Junk, StreamFrame
        from eskin.device.link import MAX_EVIDENCE_LINES

        for event in batch:
            if isinstance(event, StreamFrame):
                if self.attempt is not None and event.frame.seq != (self.last_seq + 1) % 2**32:
                    self.end()  # the board restarted, or the link was reopened
                self.last_seq = event.frame.seq
                if self.attempt is None:
                    self.attempt = self.writer.begin(
                        {"key": f"live/{self.session}/{self.attempts + 1:05d}", "live": True})
                    self.attempts += 1
                self.writer.frames(self.attempt, [event.frame])
                self.in_attempt += 1
                self.frames += 1
                if self.in_attempt >= self.chunk:
                    self.end()
            elif isinstance(event, Junk):
                if self.attempt is not None and self.rejected_in_attempt < MAX_EVIDENCE_LINES:
                    self.writer.rejected(self.attempt, [event.error])
                    self.rejected_in_attempt += 1
            else:  # a gap, an overflow: the run of frames is broken
                self.end()
        self.writer.flush()

    def end(self) -> None:
        if self.attempt is not None:
            self.writer.end(self.attempt, self.in_attempt)
        self.attempt, self.in_attempt, self.rejected_in_attempt = None, 0, 0

    def close(self) -> None:
        self.end()
        self.writer.close()
