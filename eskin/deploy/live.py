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

from eskin.config.live import Live, LiveBaseline, LiveContact
from eskin.deploy.stack import ExportedStack, RestTable, SkinStack
from eskin.kinds import get_kind

COMMANDS = ("tare",)  # what a client of the page or the JSON socket may ask for


@dataclass
class Tare:
    """A live board's offset from the training data's untouched readings, taken with
    nothing pressed, and taken off every frame after.

    The stack was trained on the training board's readings; a live board reads them
    plus an offset that wanders (temperature, humidity, the dielectric's creep), and a
    tare taken once goes stale: the stack starts seeing touches that are not there
    (issue 39). ``rest`` is what the training data read untouched at each stretch
    (:class:`~eskin.deploy.stack.RestTable`). On a frame, less the offset, the channels
    say which stretch the skin is at (their median, so that a press, which raises a few
    channels, does not move it), and so which untouched reading it should show; what is
    left is offset. The tare takes that offset, at whatever stretch the skin is, and
    :meth:`track` follows it after, with time constant ``time_constant_s`` of board time
    (0: never), on frames that (a) live judges untouched, after hysteresis, and (b) lie
    close to the expected reading in channel space (no channel's own difference, beyond
    the one common to all, above ``gate_counts``): the detector's verdict alone would
    let a light press it misses, or a press's first frames, creep into the offset. Under
    a press it is frozen (``in_contact``: wholly, or the press's terminals only), so a
    sustained press is never absorbed (iCub's skin zeroes long contacts out by following
    its baseline through them). The expected reading is worked out again on each frame,
    not remembered from a stretch's step, so an error cannot outlive the frames that made
    it. ``drift`` is how far, in counts (the largest channel), the offset has moved since
    the tare. Without a tare (:meth:`none`) there is nothing to measure drift or change
    from: both are None."""

    offset: np.ndarray
    rest: RestTable | None
    tared: np.ndarray | None = None  # the offset the tare took
    time_constant_s: float = 0.0
    gate_counts: float = np.inf
    in_contact: str = "freeze"  # quiet_channels, contact_channels (live.baseline.in_contact)
    fallen_counts: float = np.inf  # contact_channels: a contact's channel this far below
    drift_bound: float = 0.0       # ... and the drift a freeze may miss, counts per √s
    frozen_first_ms: float = 0.0   # contact_channels: a contact's first ms, frozen whole
    _contact_ms: float = 0.0       # board time the present contact has lasted
    _peak: float = 0.0             # ... and its channels' largest summed rise in it
    _pressed: bool = False         # ... and whether one of them rose beyond the gate in it
    lift_average_ms: float = 0.0   # ... whose summed rise is averaged over this long
    lifted_time_constant_ms: float = 0.0  # ... and once lifted, followed this fast
    _near: np.ndarray | None = None  # ... every terminal the contact was placed near so far
    _level: float = 0.0            # ... their summed rise, averaged over lift_average_ms
    _lifted: bool = False          # ... and whether its press has lifted

    @classmethod
    def take(cls, frames: np.ndarray, rest: RestTable | None, *,
             baseline: LiveBaseline | None = None, before: Tare | None = None) -> Tare:
        """The tare of ``frames`` (the stretch they are at read from them, less the offset
        of the tare ``before``, if any); with ``baseline`` (live.baseline), followed after."""
        mean = np.asarray(frames, dtype=np.float64).mean(axis=0)
        offset = np.zeros_like(mean)
        if rest is not None:
            drift = before.offset if before is not None and before.rest is not None else 0.0
            offset = mean - rest.at(rest.stretch_of(mean - drift))
        follow = {} if baseline is None else {
            "time_constant_s": float(baseline.time_constant_s),
            "gate_counts": float(baseline.gate_counts), "in_contact": baseline.in_contact,
            "fallen_counts": float(baseline.fallen_counts),
            "drift_bound": float(baseline.drift_counts_per_sqrt_s),
            "frozen_first_ms": 1000.0 * float(baseline.frozen_first_s),
            "lift_average_ms": 1000.0 * float(baseline.lift_average_s),
            "lifted_time_constant_ms": 1000.0 * float(baseline.lifted_time_constant_s)}
        return cls(offset, rest, None if rest is None else offset.copy(), **follow)

    @classmethod
    def none(cls, channels: int) -> Tare:
        return cls(np.zeros(channels), None)

    def apply(self, counts: np.ndarray) -> np.ndarray:
        return np.asarray(counts, dtype=np.float64) - self.offset

    def expected(self, counts: np.ndarray, *,
                 ignore: np.ndarray | None = None) -> np.ndarray | None:
        """What this board should read untouched at the stretch ``counts`` are at, as the
        channels not in ``ignore`` (a contact's) say it. In contact (``ignore`` given), up
        to the largest stretch the stack was trained on: a common rise beyond it on the
        channels a long contact leaves (drift, which reads as stretch) is not read as a
        stretch the detector never saw, but left as offset for :meth:`track` to follow
        (without it, the real-drift test of tests/test_live_ghosts.py had a phantom 450 s
        after the release). Untouched, not bounded: the skin sits at the least or the
        largest stretch, its reading either side of it, and a bound there took one side
        into the offset alone (at the least: ten untouched minutes 1.6 % contact; at the
        largest, the live hour's 16 mm: 1.76 % phantom and 2.05 % missed frames against
        none and 1.05 % unbounded, issue 57)."""
        if self.rest is None:
            return None
        stretch = self.rest.stretch_of(self.apply(counts), ignore=ignore)
        if stretch is not None and ignore is not None:
            stretch = min(stretch, float(self.rest.stretch[-1]))
        return self.rest.at(stretch) + self.offset

    def track(self, counts: np.ndarray, elapsed_ms: float, *,
              under_contact: np.ndarray | None = None) -> bool:
        """Follow a frame ``elapsed_ms`` after the last; whether any of it was taken.

        Untouched (``under_contact`` None): every channel not raised beyond the gate (a
        channel raised further may be a press not yet declared, or one the detector
        misses, and waits; one fallen below is followed back, as no press lowers a
        reading: capacitive touch controllers' "anti-touch" recalibration).

        In contact, ``under_contact`` are the contact's channels (the terminals within
        reach of its location, a press's flanks included; with ``contact_channels``,
        within reach of any location it had since it began). ``contact_channels``: for the
        contact's first ``frozen_first_ms`` nothing is followed, once one of its
        channels rose beyond the gate (a press's time: the drift it may hide is under a
        count); after, the other channels are followed as on an untouched frame (a
        second press beyond the gate waits), so drift is followed everywhere the contact
        is not; the contact's own channels stay frozen, so a sustained press is never
        absorbed, except where they cannot be the press: (a) a channel more than
        ``fallen_counts`` below its expected untouched reading (no press lowers a
        reading: its baseline is stale), and (b) once the contact's summed rise
        (averaged over ``lift_average_ms``) has fallen to half its peak in this contact
        (the press lifted) and what is left on each of its channels is within the drift
        the freeze may have missed (``drift_bound`` counts per √s of the contact's board
        time, a random walk's growth): what is left is that drift, and is followed with
        time constant ``lifted_time_constant_ms``, so that the phantom a release would
        leave ends within a second.
        ``quiet_channels``: the channels within the gate, but where some channel is
        beyond it, not the contact's; a contact with every channel within the gate is
        followed. ``freeze``: nothing is followed in contact."""
        if self.rest is None or self.time_constant_s <= 0:
            return False
        touching = under_contact is not None
        if not touching:
            self._contact_ms, self._peak, self._pressed = 0.0, 0.0, False
            self._near, self._level, self._lifted = None, 0.0, False
        if touching and self.in_contact == "freeze":
            return False
        if touching and self.in_contact == "contact_channels":
            # every terminal the contact was placed near since it began: a count that
            # flickers (two contacts, then one) frees none of the other's channels (it
            # freed them, they were followed into the press, and the harder hour's
            # 10-minute light pair was lost after about 450 s, issue 57)
            self._near = under_contact if self._near is None else self._near | under_contact
            under_contact = self._near
        # in contact the stretch is the other channels' to say: a press raises its own
        # (half of a 10 x 10 skin's within reach 2), and a stretch read from them all
        # would move every expected reading, and the offset followed toward it
        ignore = under_contact if touching and self.in_contact == "contact_channels" \
            else None
        error = np.asarray(counts, dtype=np.float64) - self.expected(counts, ignore=ignore)
        own = error - np.median(error if ignore is None or ignore.all() else error[~ignore])
        if not touching:
            quiet = own <= self.gate_counts
        elif self.in_contact == "quiet_channels":
            quiet = np.abs(own) <= self.gate_counts
            if not quiet.all():
                quiet &= ~under_contact
        else:
            quiet = self._contact_channels(own, max(elapsed_ms, 0.0), under_contact)
        if not quiet.any():
            return False
        # an exponential average in board time: the same for any frame rate or lost frames
        weight = _share(elapsed_ms, 1000.0 * self.time_constant_s)
        if touching and self._lifted:  # what a lifted press left is drift the freeze
            # missed, and a phantom until it is followed: so followed fast
            weight = np.where(under_contact, _share(elapsed_ms, self.lifted_time_constant_ms),
                              weight)
        self.offset = self.offset + np.where(quiet, weight * error, 0.0)
        return True

    def _contact_channels(self, own: np.ndarray, elapsed_ms: float,
                          near: np.ndarray) -> np.ndarray:
        """Which channels a contact frame follows (``contact_channels``, :meth:`track`)."""
        self._contact_ms += elapsed_ms
        quiet = (~near & (own <= self.gate_counts)) | (own < -self.fallen_counts)
        rise = float(np.clip(own[near], 0.0, None).sum())
        # averaged, so that a frame's noise (about a count a channel) neither sets the
        # peak nor passes for a lifted press
        self._level += (_share(elapsed_ms, self.lift_average_ms) if self._peak else 1.0) \
            * (rise - self._level)
        self._peak = max(self._peak, self._level)
        self._pressed |= bool((own[near] > self.gate_counts).any())
        missed = self.drift_bound * math.sqrt(self._contact_ms / 1000.0)
        self._lifted = False
        if self._contact_ms < self.frozen_first_ms and self._pressed:
            # A press's first seconds hide no drift worth following: followed from its
            # first frame, the live hour (seed 39) had 4.2 % phantom frames at 16 mm,
            # none frozen whole. A contact none of whose channels rose beyond the gate
            # is no press the gate can tell from drift, and is not held: with real-sized
            # drift each phantom there lasted the hold (0.67 % of the hour's untouched
            # frames held 10 s whatever the contact, 0.018 % held only a press's).
            return np.zeros_like(quiet)
        self._lifted = self._level <= self._peak / 2 and bool((own[near] <= missed).all())
        if self._lifted:
            quiet |= near
        return quiet

    @property
    def drift(self) -> float | None:
        if self.tared is None:
            return None
        return round(float(np.max(np.abs(self.offset - self.tared))), 3)


def _share(elapsed_ms: float, time_constant_ms: float) -> float:
    """How much of the way an exponential average of this time constant moves in
    ``elapsed_ms`` of board time (all of it at a time constant of 0)."""
    if time_constant_ms <= 0:
        return 1.0
    return -math.expm1(-max(elapsed_ms, 0.0) / time_constant_ms)


@dataclass
class ContactHysteresis:
    """Contact as live reports it, from the stack's contact probability frame by frame:
    it begins once the probability has stayed at or above ``enter`` for
    ``min_duration_ms`` of board time, and ends once it has stayed below ``leave`` as
    long. Between the two thresholds, and for a shorter excursion, it stays as it was: a
    detector near its threshold (noise, drift, a light or an edge press) does not make
    contact flicker. Applied to the stack's outputs, so the scikit-learn and the ONNX
    stacks behave the same."""

    enter: float
    leave: float
    min_duration_ms: float
    touching: bool = False
    _since_ms: float | None = None  # board time the other verdict began, while it lasts

    @classmethod
    def of(cls, contact: LiveContact) -> ContactHysteresis:
        return cls(float(contact.enter_probability), float(contact.leave_probability),
                   float(contact.min_duration_ms))

    def update(self, probability: float, t_ms: float) -> bool:
        """The contact verdict after a frame at board time ``t_ms`` whose probability is
        ``probability``."""
        other = probability < self.leave if self.touching else probability >= self.enter
        if not other:
            self._since_ms = None
        else:
            if self._since_ms is None:
                self._since_ms = t_ms
            if t_ms - self._since_ms >= self.min_duration_ms:
                self.touching, self._since_ms = not self.touching, None
        return self.touching

    def reset(self) -> None:
        self.touching, self._since_ms = False, None


def _number(value: Any) -> Any:
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (float, np.floating)):
        return None if math.isnan(value) else round(float(value), 6)
    if isinstance(value, (np.integer,)):
        return int(value)
    return value


def live_estimates(stack: SkinStack | ExportedStack, batches: Iterable[list], *,
                   tare_frames: int | None = None, settings: Live | None = None,
                   with_change: bool = False,
                   requests: Callable[[], Iterable[str]] = tuple,
                   notify: Callable[[str], object] = lambda message: None
                   ) -> Iterator[dict[str, Any]]:
    """One record per stream event, in order: an estimate per frame (``seq``, ``t_ms``,
    the stack's columns and the drift since the tare), ``{"gap": ...}`` for lost frames,
    ``{"rejected": ...}`` for a line that failed its check. The first ``tare_frames``
    frames (default ``settings.tare_frames``) are the tare (nothing may be pressed),
    reported once as ``{"tare": ...}`` (``tare_frames=0``: no tare). ``batches`` are the
    events as they arrived: a batch's frames are predicted together, as a scikit-learn
    call costs milliseconds whatever its rows, so the stack keeps up with the board.

    ``settings`` (params.yaml's ``live``) are the baseline tracking (:class:`Tare`) and
    the contact hysteresis (:class:`ContactHysteresis`) of a stack that detects contact:
    an estimate's ``contact`` is the hysteresis' verdict, ``stack_contact`` the stack's
    own on that frame; while in contact a frame the stack did not locate keeps the last
    location and force, while untouched none is given. ``requests`` is asked before each
    batch for commands (``"tare"``: the next tare's frames, ``settings.tare_frames`` or
    100 without a start tare, are taken while estimates go on, and reported as the first
    tare is). ``with_change``: each estimate also carries ``change_counts``, every
    channel's change from the followed untouched reading (the live view's bars)."""
    from eskin.device.host import Junk, StreamFrame, StreamGap
    from eskin.device.link import StreamOverflow

    settings = Live() if settings is None else settings
    tare_frames = settings.tare_frames if tare_frames is None else tare_frames
    retare_frames = tare_frames or Live().tare_frames
    detects = "contact" in stack.columns
    positions = get_kind(stack.kind).positions.values()
    hysteresis = ContactHysteresis.of(settings.contact)
    located = {name: None for name in stack.columns
               if name not in ("stretch", "contact", "contact_probability")}
    taring: list[np.ndarray] | None = [] if tare_frames > 0 else None
    wanted, why = tare_frames, "start"
    tare = Tare.none(stack.skin.terminals) if tare_frames <= 0 else None
    last_t_ms: float | None = None
    for batch in batches:
        for command in requests():
            if command == "tare" and taring is None:
                taring, wanted, why = [], retare_frames, "request"
                notify(f"re-taring on the next {wanted} frames: keep the skin untouched")
            elif command not in COMMANDS:
                notify(f"ignored the request {command!r} (known: {', '.join(COMMANDS)})")
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
                if taring is None:
                    continue
                taring.append(counts)
                if len(taring) == wanted:
                    tare = Tare.take(np.array(taring), stack.rest, baseline=settings.baseline,
                                     before=tare)
                    taring = None
                    hysteresis.reset()
                    notify(f"tared on {wanted} frames" + (" (requested)" if why != "start"
                                                          else ""))
                    records.append({"tare": {"frames": wanted, "reason": why,
                                             "at_seq": event.frame.seq, "offset_counts":
                                             [round(float(v), 3) for v in tare.offset]}})
        if pending:
            counts = np.array([frame.counts for _, frame in pending], dtype=np.float64)
            predicted = stack.predict(tare.apply(counts))
            estimates = {name: predicted[name].to_numpy() for name in stack.columns}
            for row, (at, frame) in enumerate(pending):
                record = {"seq": frame.seq, "t_ms": frame.t_ms}
                record.update({name: _number(estimates[name][row]) for name in stack.columns})
                if detects:
                    contact_of_frame(record, hysteresis, located)
                    if taring is None and last_t_ms is not None:
                        tare.track(counts[row], frame.t_ms - last_t_ms,
                                   under_contact=terminals_under(
                                       record, stack.skin, settings.baseline.reach_terminals,
                                       positions)
                                   if record["contact"] else None)
                last_t_ms = frame.t_ms
                record["drift_counts"] = tare.drift
                if with_change:
                    expected = tare.expected(counts[row])
                    record["change_counts"] = None if expected is None else [
                        round(float(v), 1) for v in counts[row] - expected]
                records[at] = record
        yield from records


def terminals_under(record: dict[str, Any], skin, reach: int,
                    positions: Iterable[tuple[str, str]] = (("x", "y"),)) -> np.ndarray:
    """Which of a row/column skin's terminals (x then y) are within ``reach`` of the
    contacts ``record`` places (each of ``positions``, its kind's (x, y) columns, that
    is not None); every one where it places none."""
    placed = [(record[x], record[y]) for x, y in positions
              if record.get(x) is not None and record.get(y) is not None]
    if not placed or not skin.row_column:
        return np.ones(skin.terminals, dtype=bool)
    under = np.zeros(skin.terminals, dtype=bool)
    for x, y in placed:
        under |= np.concatenate([np.abs(np.arange(1, skin.rows + 1) - x) <= reach,
                                 np.abs(np.arange(1, skin.columns + 1) - y) <= reach])
    return under


def contact_of_frame(record: dict[str, Any], hysteresis: ContactHysteresis,
                     located: dict[str, Any]) -> None:
    """``record`` (one frame's estimate from a detecting stack) with the hysteresis'
    contact in place of the stack's (kept as ``stack_contact``), and the location and
    force made to agree with it: the last located ones held while in contact, none while
    untouched. ``located`` keeps the last located values between frames."""
    detected = bool(record["contact"])
    probability = record.get("contact_probability")
    if probability is None:  # a detector without probabilities (the paper's SVM)
        probability = float(detected)
    touching = hysteresis.update(probability, record["t_ms"])
    record["stack_contact"], record["contact"] = detected, touching
    if detected:
        located.update({name: record[name] for name in located})
    for name in located:
        if touching and not detected:
            record[name] = located[name]
        elif not touching and detected:
            record[name] = 0.0 if name.startswith("force") or name == "contacts" else None


def _command(line: bytes) -> str:
    """The command a client's line asks for (``{"command": "tare"}``), or why it is none."""
    try:
        message = json.loads(line)
    except (ValueError, UnicodeDecodeError):
        return f"not a JSON line: {line[:60]!r}"
    command = message.get("command") if isinstance(message, dict) else None
    if command in COMMANDS:
        return command
    return (f"unknown command {command!r}: send {{\"command\": \"tare\"}}" if command
            else 'a command is {"command": "tare"}')


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
    that does not read is dropped, and the live loop never waits for anybody.

    A client may send commands, one JSON line each: ``{"command": "tare"}``.
    :meth:`requests` gives those received since it was last asked; a line that is not a
    known command is answered to its client alone with ``{"error": ...}``."""

    def __init__(self, port: int = 0, *, max_backlog: int = 1 << 20,
                 notify: Callable[[str], object] = lambda message: None) -> None:
        import socket

        self._server = socket.create_server(("127.0.0.1", port))
        self._server.setblocking(False)
        self.port = self._server.getsockname()[1]
        self.max_backlog = max_backlog
        self.notify = notify
        self._clients: dict[Any, bytearray] = {}
        self._received: dict[Any, bytearray] = {}

    def _accept(self) -> None:
        while True:
            try:
                client, address = self._server.accept()
            except BlockingIOError:
                return
            client.setblocking(False)
            self._clients[client] = bytearray()
            self.notify(f"client {address[0]}:{address[1]} connected")

    def requests(self) -> list[str]:
        """The commands clients sent since the last call, in order."""
        self._accept()
        commands = []
        for client in list(self._clients):
            try:
                data = client.recv(4096)
            except BlockingIOError:
                continue
            except OSError:
                self._drop(client, "disconnected")
                continue
            if not data:  # the client closed its end
                self._drop(client, "disconnected")
                continue
            pending = self._received.setdefault(client, bytearray())
            pending += data
            while (end := pending.find(b"\n")) >= 0:
                line = bytes(pending[:end]).strip()
                del pending[: end + 1]
                if line:
                    command = _command(line)
                    if command in COMMANDS:
                        commands.append(command)
                    else:
                        self._queue(client, json_line({"error": command}))
            if len(pending) > 4096:  # no newline in sight: not a command line
                pending.clear()
                self._queue(client, json_line({"error": "a command line is one short "
                                               "JSON object ending in a newline"}))
        return commands

    def send(self, line: str) -> None:
        self._accept()
        for client in list(self._clients):
            self._queue(client, line)

    def _queue(self, client, line: str) -> None:
        data = (line + "\n").encode()
        backlog = self._clients.get(client)
        if backlog is not None:
            backlog += data
            try:
                sent = client.send(backlog)
                del backlog[:sent]
            except BlockingIOError:
                pass
            except OSError:  # the client went away
                self._drop(client, "disconnected")
                return
            if len(backlog) > self.max_backlog:
                self._drop(client, f"dropped: more than {self.max_backlog} bytes unread")

    def _drop(self, client, why: str) -> None:
        self._clients.pop(client, None)
        self._received.pop(client, None)
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
        from eskin.data.rawlog import LOG_NAME, RawLogWriter, read_log_if_any

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
