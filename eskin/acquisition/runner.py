"""The acquisition runner: walks a scene's plan over a serial link into a raw log.

For each condition not yet recorded on this device it sets the stretch,
has the indenters placed — by ``SIM`` commands on the simulated board, by a
person prompted at the terminal on a real one — and asks for the samples. A
condition is stored only whole. A frame that fails its CRC, is malformed or
never arrives leaves its place in the answer empty (the sequence number places
the others); the attempt is logged as abandoned, its valid frames are kept, and
the condition is asked again for its missing places only, the weights left
where they lie (the simulated board replays those frames of the trial, so a
faulty link still gives the clean run's data). Once every place is filled, the
frames are stored: as the attempt that brought them, or, if several did, as a
record assembled from them. A reading that jumps far from the rest of its
condition (a damaged frame whose CRC-8 matched by chance) empties its place. A
board that restarts mid-condition (``#HELLO``) gets its stretch and indenters
again; a port that fails is reopened with backoff, and only the same board is
accepted back. Those link faults do not count as attempts at the condition: it is
given up on after ``max_attempts`` answers, or ``max_interruptions`` requests cut
short.
"""

from __future__ import annotations

import logging
import sys
import time
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Protocol

from tqdm import tqdm

from eskin.data.plan import Condition, ScenePlan
from eskin.data.rawlog import RawLogWriter
from eskin.device.link import (
    BoardRefused,
    BoardReset,
    DeviceChanged,
    LinkError,
    ProtocolViolation,
    SampleBatch,
    SerialLink,
    digits_lost,
)
from eskin.device.protocol import Frame
from eskin.errors import EskinError

log = logging.getLogger(__name__)


class AcquisitionError(EskinError, RuntimeError):
    """Acquisition could not complete a condition."""


@dataclass
class AcquisitionReport:
    scene: str
    port: str
    conditions: int
    reused: int
    acquired: int
    retries: int
    frames_stored: int
    frames_rejected: int
    seconds: float
    resets: int = 0        # the board restarted mid-trial
    reconnects: int = 0    # the link failed and was reopened

    @property
    def frames_per_s(self) -> float:
        return self.frames_stored / self.seconds if self.seconds > 0 else 0.0

    def summary(self) -> str:
        return (f"{self.scene}: {self.acquired} trial(s) acquired, {self.reused} reused "
                f"of {self.conditions}; {self.frames_stored} frames stored, "
                f"{self.frames_rejected} rejected, {self.retries} retried trial(s), "
                f"{self.resets} board restart(s), {self.reconnects} reconnect(s); "
                f"{self.seconds:.1f} s ({self.frames_per_s:.0f} frames/s over {self.port})")


def trial_seed(key: str) -> int:
    """The simulated board's trial number for a condition key (60 bits)."""
    return int(key[:15], 16)


class Placer(Protocol):
    """The bench's hands: they place a condition's weights (once per condition, and again
    only for a board that may have forgotten them: a restart, a reconnect), and before a
    condition is asked again, let the board answer for the ``missing`` places of an
    ``n``-sample answer: they return the places the next ``SAMPLE`` answers, in order
    (``missing``, or more where the board can only answer from the first of them on)."""

    def place(self, link: SerialLink, condition: Condition, key: str, repeat: bool) -> None: ...

    def replay(self, link: SerialLink, missing: list[int], n: int) -> list[int]: ...


# Longest SIM PICK line sent: a board takes command lines of up to 256 bytes.
MAX_PICK_LINE = 240


def _picked(missing: list[int], n: int) -> tuple[list[int], str | None]:
    """The places a top-up asks for (a place named twice is asked twice) and the ``SIM
    PICK`` that asks for them; no command (None) when ``SIM REPLAY <first>`` asks for
    exactly those (one run to the end), or when the line would be too long: then from
    the first missing place on."""
    first = missing[0]
    line = f"SIM PICK {n} " + " ".join(map(str, missing))
    if missing == list(range(first, n)) or len(line) > MAX_PICK_LINE:
        return list(range(first, n)), None
    return missing, line


class SimulatedPlacer:
    """Places indenters on the simulated board with SIM commands; the placements come from
    the condition's trial (``SIM TRIAL``), so placing them again places them alike."""

    def place(self, link: SerialLink, condition: Condition, key: str, repeat: bool) -> None:
        link.command("SIM CLEAR")
        link.command(f"SIM TRIAL {trial_seed(key)}")
        for contact in condition.contacts:
            if contact.touches:
                link.command(f"SIM PRESS {contact.x} {contact.y} {contact.force!r}")

    def __init__(self) -> None:
        self.picks = True  # the board takes SIM PICK (a board older than it answers #ERR)

    def replay(self, link: SerialLink, missing: list[int], n: int) -> list[int]:
        """``SIM PICK`` (or ``SIM REPLAY``): the frames asked again read as in the trial's
        first answer."""
        places, pick = _picked(missing, n)
        if pick is not None and self.picks:
            try:
                link.command(pick)
                return places
            except BoardRefused:
                self.picks = False  # an older simulated board: from the first on, as then
        link.command(f"SIM REPLAY {missing[0]}")
        return list(range(missing[0], n))


class EmulatedPlacer:
    """Places the weights on the emulated rig (:mod:`eskin.device.emulated`), as a person
    does on a bench: the firmware knows nothing of them. Each condition's trial is the one
    the Python board draws for it (its key on that board), so that an emulated and a
    simulated acquisition of the same plan compare sample by sample."""

    def __init__(self, rig, simulated_id: str, simulated_firmware: str) -> None:
        self.rig = rig
        self.simulated = (simulated_id, simulated_firmware)

    def place(self, link: SerialLink, condition: Condition, key: str, repeat: bool) -> None:
        link.quiet()  # the rig draws scans in order: none may go to an earlier answer
        self.rig.place(trial_seed(condition.key(*self.simulated)),
                       [(c.x, c.y, c.force) for c in condition.contacts if c.touches])

    def replay(self, link: SerialLink, missing: list[int], n: int) -> list[int]:
        """The rig rewinds the trial: the firmware's next scans read the places asked for.
        The firmware must first have sent all it owed (:meth:`SerialLink.quiet`): after an
        answer broken off (a violation), it scans on for the frames it still owes, and
        those scans would take the replayed places, each later frame one place off."""
        link.quiet()
        places, pick = _picked(missing, n)
        if pick is None:
            self.rig.replay(places[0])
        else:
            self.rig.pick(places)
        return places


class OperatorPlacer:
    """Asks a person to place the weights, only when what lies on the skin changes."""

    def __init__(self, ask: Callable[[str], object] = input) -> None:
        self.ask = ask
        self._on_skin: tuple | None = None

    def place(self, link: SerialLink, condition: Condition, key: str, repeat: bool) -> None:
        touching = tuple(c for c in condition.contacts if c.touches)
        if repeat or touching == self._on_skin:
            return
        what = "; ".join(f"{c.force:g} N on node x={c.x}, y={c.y}" for c in touching)
        prompt = (f"[{condition.describe()}] "
                  f"{'Place ' + what if touching else 'Remove all weights'}, then press Enter: ")
        try:
            self.ask(for_terminal(prompt, sys.stdout))
        except EOFError:
            raise AcquisitionError(
                f"operator input closed at the prompt for {condition.describe()}: acquiring "
                "from a real board needs a person at a terminal to place the weights (set "
                "acquire.indenters: board only for a board that places them itself); "
                "everything recorded so far is kept, rerun to resume") from None
        self._on_skin = touching

    def replay(self, link: SerialLink, missing: list[int], n: int) -> list[int]:
        """Nothing: a real board reads on, the weights where they lie; its next frames fill
        the missing places (samples of one static load are alike in all but noise)."""
        return missing


def for_terminal(text: str, stream) -> str:
    """``text`` as ``stream`` can show it: an ASCII-only terminal gets ``stretch=`` for
    ``λ=`` and escapes for anything else it cannot encode."""
    encoding = getattr(stream, "encoding", None) or "ascii"
    try:
        text.encode(encoding)
        return text
    except (UnicodeEncodeError, LookupError):
        text = text.replace("λ", "stretch")
        return text.encode("ascii", "backslashreplace").decode("ascii")


def acquire(plan: ScenePlan, link: SerialLink, writer: RawLogWriter, placer: Placer, *,
            completed: dict[str, int], rest_length_mm: float, max_attempts: int = 5,
            max_interruptions: int = 20, reconnect_s: float = 30.0,
            max_jump_counts: float = 40.0,
            progress: bool = True,
            notify: Callable[[str], object] | None = None) -> AcquisitionReport:
    """Acquire every condition of ``plan`` not yet recorded whole: its key is not in
    ``completed`` (key -> frames of its latest complete attempt), or with fewer frames
    than the plan's samples (a plan whose ``samples`` grew).

    A condition is given up on after ``max_attempts`` answers (requests the board
    answered to the end, however damaged their frames) or ``max_interruptions``
    requests cut short (a board restart, a port that failed, a silence past the link's
    timeout): those are the link's faults, not attempts at the condition, and the
    link already bounds each one's wait. The valid frames of each answer are kept in
    their places, and an answer that lost frames is followed by a request for its
    missing places only (the simulated board replays them, a real one reads on, the
    weights where they lie). A board that restarts gets its
    stretch and indenters again; a link that fails is reopened with backoff for up to
    ``reconnect_s``. Every frame that arrived, in whole attempts or not, is in the log
    before any error or Ctrl-C leaves this function.
    """
    hello = link.hello
    if hello is None:
        raise AcquisitionError(f"no #HELLO from the board on {link.port}: call connect() first")
    started = time.monotonic()
    report = AcquisitionReport(plan.name, link.port, len(plan.conditions), 0, 0, 0, 0, 0, 0.0)
    stretch_mm: str | None = None
    n = plan.samples
    bar = tqdm(total=len(plan.conditions), desc=f"acquire {plan.name}", unit="cond",
               disable=not progress, leave=False)
    say = notify or (lambda message: tqdm.write(f"acquire {plan.name}: {message}",
                                                file=sys.stderr))
    queue: deque[tuple[Condition, _Carried | None]] = deque(
        (condition, None) for condition in plan.conditions)
    # A condition whose places are all filled, held until the board's next frame has
    # judged its last one (board time: TimeJumped), then stored or asked again.
    pending: _Pending | None = None

    def settle(*, force: bool = False) -> None:
        """Store the pending condition if the frame after its last one vouched for it; put
        it back in the queue with that place empty if that frame jumped forward, or if the
        board restarted before anything judged it (or ``force``); else leave it pending."""
        nonlocal pending
        held = pending
        if held is None or (link.protocol.watch_open and not force):
            return
        pending = None
        still_open = writer.open_attempt  # its records may follow a later attempt's B
        if link.protocol.watched_verdict is True:
            _store(writer, held.record, held.kept, held.attempt, held.frames, held.logged)
            report.frames_stored += n
            completed[held.key] = n
            report.acquired += 1
            bar.update()
        else:
            why = ("its last frame's board time jumped forward (the next frame fell below it)"
                   if link.protocol.watched_verdict is False else
                   "nothing the board sent after its last frame judged that frame's board "
                   "time")
            _close(writer, held.attempt, f"{why}: asked again")
            del held.kept[held.place]
            report.retries += 1
            queue.append((held.condition,
                          _Carried(held.kept, held.answers, held.interruptions)))
        if still_open != held.attempt:
            writer.open_attempt = still_open

    with bar, _closed_on_the_way_out(writer), _held_on_the_way_out(writer, lambda: pending):
        while queue or pending is not None:
            if not queue:  # the last condition's last frame: one more frame judges it
                fault = _judge(link, settle)
                if fault is not None:
                    # As below: a restarted board forgot where the clamp is (the condition
                    # put back is placed anew, but its stretch is sent only if it changed).
                    report.resets += isinstance(fault, BoardReset)
                    stretch_mm = None
                continue
            condition, carried = queue.popleft()
            key = condition.key(hello.device_id, hello.firmware)
            if carried is None and completed.get(key, 0) >= plan.samples:
                report.reused += 1
                bar.update()
                continue
            wanted_mm = f"{(condition.stretch - 1.0) * rest_length_mm:.3f}"
            record = {"key": key, "scene": plan.name, **condition.as_dict()}
            # place -> (attempt, its first valid copy)
            kept: dict[int, tuple[int, Frame]] = carried.kept if carried else {}
            placed = False  # the board holds this condition's weights
            problem = None
            answers = carried.answers if carried else 0
            interruptions = carried.interruptions if carried else 0
            asked = 0  # requests for it since it was taken from the queue
            tries: dict[int, int] = {}  # place -> requests that asked for it
            while True:
                asked_before = answers + interruptions > 0
                missing = sorted(set(range(n)) - kept.keys())
                attempt = number = batch = None
                cut_short = False  # a link fault ended the request, not the board's answer
                try:
                    if wanted_mm != stretch_mm:
                        link.command(f"STRETCH {wanted_mm}")
                        stretch_mm = wanted_mm
                    if not placed:
                        # Put back in the queue, it is placed anew: another condition's
                        # weights lie on the skin now.
                        placer.place(link, condition, key, repeat=asked > 0)
                        placed = True
                    # A top-up asks only for the places missing (issue 56): the frames
                    # of the answer fill them in order.
                    # A place asked for twice in vain is asked for twice in one request:
                    # at 10 % of lines damaged, a place lost 4 times running ended the
                    # condition about once in 10,000 places; so, once in 10 million.
                    wanted = [place for place in missing
                              for _ in range(2 if tries.get(place, 0) >= 2 else 1)]
                    places = (placer.replay(link, wanted, n) if asked_before
                              else list(range(n)))
                    batch = SampleBatch(len(places))
                    if pending is None:
                        attempt = number = writer.begin(record)
                    try:
                        link.sample(batch)
                    finally:  # an error or Ctrl-C mid-batch: what arrived is kept
                        if attempt is None:  # its frames judged the pending condition
                            settle()
                            attempt = number = writer.begin(record)
                        writer.frames(attempt, batch.frames)
                        writer.rejected(attempt, batch.rejected)
                        report.frames_rejected += batch.rejected_count
                    problem = batch.problem
                except BoardRefused as err:
                    _close(writer, attempt, str(err))
                    raise AcquisitionError(
                        f"{plan.name}: {condition.describe()}: {err}. A board that refuses "
                        "a command will refuse it again, so the run stops here; the "
                        f"{report.acquired + report.reused} condition(s) complete so far are "
                        f"kept in {writer.path}, and rerunning resumes after the last of "
                        "them.") from err
                except DeviceChanged as err:
                    _close(writer, attempt, "another board answered")
                    raise AcquisitionError(
                        f"{plan.name}: {err}. Nothing from it was stored; everything the "
                        f"session's board sent is in {writer.path}.") from err
                except ProtocolViolation as err:
                    # A command answered out of turn (a stray #OK, say), fenced: the link's
                    # fault, not an answer to the condition's request, and bounded as one.
                    problem = str(err)
                    cut_short = True
                except BoardReset as err:
                    problem = str(err)
                    cut_short = True
                    report.resets += 1
                    stretch_mm = None  # a restarted board forgot where the clamp is
                    placed = False     # and the indenters
                except LinkError as err:
                    problem = str(err)
                    cut_short = True
                    _close(writer, attempt, problem)
                    attempt = None
                    report.reconnects += 1
                    stretch_mm = None  # the board may have restarted while the link was down
                    placed = False
                    try:
                        link.reopen(budget_s=reconnect_s, notify=say)
                    except LinkError as lost:
                        raise AcquisitionError(
                            f"{plan.name}: {lost}. Everything received is in {writer.path}; "
                            "rerun to resume.") from lost
                asked += 1
                if cut_short:
                    interruptions += 1
                else:
                    answers += 1
                if batch is not None:
                    _keep(kept, batch, places, number, n)
                    if batch.frames or batch.rejected_count:  # the board answered: a try
                        for place in set(places):
                            tries[place] = tries.get(place, 0) + 1
                for frame in link.take_jumped():  # judged by a frame of this request
                    _drop(kept, frame)
                if len(kept) == n:
                    settle(force=True)  # (frames came: it was judged) before another waits
                    frames = [kept[place][1] for place in range(n)]
                    lost = digits_lost(frames, max_jump_counts)
                    if lost is None:
                        tail = _tail(kept, link.protocol.last_accepted)
                        if tail is None:  # the frame after the last one judged it
                            _store(writer, record, kept, attempt, frames,
                                   len(batch.frames) if batch else None)
                            report.frames_stored += n
                            completed[key] = n
                            report.acquired += 1
                            bar.update()
                            break
                        if link.protocol.last_accepted is tail[1]:
                            link.protocol.watch(tail[1])  # the next request's frames judge it
                            pending = _Pending(condition, key, record, kept, attempt, frames,
                                               tail[0], tail[1], answers, interruptions,
                                               len(batch.frames) if batch else None)
                            break
                        # The board's time started again (a restart) before a frame after
                        # the last one came: nothing can judge it; ask for its place again.
                        place, problem = tail[0], ("the board's time started again before "
                                                   "its last frame was judged")
                    else:
                        place, problem = lost
                    del kept[place]  # asked again with what follows it
                _close(writer, attempt, problem if len(kept) == 0 else
                       f"{problem}; {len(kept)} of {n} frames kept")
                if answers >= max_attempts:
                    raise AcquisitionError(
                        f"{plan.name}: {condition.describe()} failed {max_attempts} times "
                        f"(acquire.max_attempts) on {link.port} ({len(kept)} of its {n} "
                        f"frames arrived valid), last: {problem}. Received data is in "
                        f"{writer.path}; rerun to resume.")
                if interruptions >= max_interruptions:
                    raise AcquisitionError(
                        f"{plan.name}: {condition.describe()} was cut short {interruptions} "
                        f"times (acquire.max_interruptions) on {link.port} by board "
                        f"restarts, a failing port, silences past acquire.timeout_s or "
                        f"commands answered out of turn "
                        f"({answers} answer(s), {len(kept)} of its {n} frames valid), last: "
                        f"{problem}. Check the board's supply and cable, or raise "
                        f"acquire.max_interruptions; received data is in {writer.path}, "
                        "rerun to resume.")
                report.retries += 1
                log.info("%s: %s; asking again (%d answer(s), %d interruption(s) so far)",
                         condition.describe(), problem, answers, interruptions)
    report.seconds = time.monotonic() - started
    return report


@contextmanager
def _closed_on_the_way_out(writer: RawLogWriter) -> Iterator[None]:
    """Ctrl-C, or a bug, wherever it lands (in a batch, or between a condition's last
    frames and its end record): the attempt left open is marked abandoned, then stop."""
    try:
        yield
    except BaseException:
        _close(writer, writer.open_attempt, "interrupted")
        raise


@contextmanager
def _held_on_the_way_out(writer: RawLogWriter,
                         held: Callable[[], _Pending | None]) -> Iterator[None]:
    """An error or Ctrl-C with a condition held for its last frame's verdict: its attempt
    is marked abandoned (its frames are in the log; a rerun asks for it again)."""
    try:
        yield
    except BaseException:
        pending = held()
        if pending is not None and pending.attempt is not None:
            still_open = writer.open_attempt
            _close(writer, pending.attempt, "every frame came, but the run stopped before a "
                   "frame after its last one judged that frame's board time: asked again "
                   "on a rerun")
            if still_open != pending.attempt:
                writer.open_attempt = still_open
        raise


@dataclass
class _Carried:
    """What a condition put back in the queue keeps: its valid frames and its counts."""

    kept: dict[int, tuple[int, Frame]]
    answers: int
    interruptions: int


@dataclass
class _Pending:
    """A condition with every place filled whose last frame (``tail``, at ``place``) awaits
    the board's next frame to judge its time."""

    condition: Condition
    key: str
    record: dict
    kept: dict[int, tuple[int, Frame]]
    attempt: int | None
    frames: list[Frame]
    place: int
    tail: Frame
    answers: int
    interruptions: int
    logged: int | None  # frames logged under ``attempt``


def _judge(link: SerialLink, settle: Callable[..., None]) -> LinkError | None:
    """After the plan's last condition: one frame more, asked for nothing but to judge the
    board time of the frame before it (none of it is stored). The link fault that cut
    that request short, if one did: a restart (BoardReset) or a lost link may have left
    the board without its stretch, and the caller must know to set it again."""
    fault = None
    try:
        link.sample(SampleBatch(1))
    except ProtocolViolation:
        pass  # answered out of turn, fenced: nothing judged it
    except LinkError as err:
        if isinstance(err, BoardRefused | DeviceChanged):
            raise
        fault = err  # nothing judged it either
    settle(force=True)  # a frame judged it, or none will: it is asked again
    return fault


def _tail(kept: dict[int, tuple[int, Frame]], last: Frame | None) -> tuple[int, Frame] | None:
    """The kept frame the board sent last, with its place, if nothing judged it yet: the
    board-time check's last frame (``last``), or any if its time started again (None).
    None if a frame after all of them came (every one was judged)."""
    if last is None:
        place, (_, frame) = max(kept.items(), key=lambda item: (item[1][0], item[1][1].seq))
        return place, frame
    for place, (_, frame) in kept.items():
        if frame is last:
            return place, frame
    return None


def _drop(kept: dict[int, tuple[int, Frame]], frame: Frame) -> None:
    """Empty the place of ``frame`` (judged to have jumped forward), if it is kept."""
    for place, (_, mine) in list(kept.items()):
        if mine is frame:
            del kept[place]


def _keep(kept: dict[int, tuple[int, Frame]], batch: SampleBatch, places: list[int],
          attempt: int, n: int) -> None:
    """Keep the placed frames of ``batch``, an answer for ``places`` (its frame i for place
    ``places[i]``), where no valid frame is kept yet; a whole answer for all ``n`` places
    replaces what was kept, so that it is stored as it came."""
    placed = batch.placed()
    if places == list(range(n)) and len(placed) == batch.requested:
        kept.clear()
    for index, frame in placed.items():
        kept.setdefault(places[index], (attempt, frame))


def _store(writer: RawLogWriter, record: dict, kept: dict[int, tuple[int, Frame]],
           attempt: int | None, frames: list[Frame], logged: int | None) -> None:
    """Close the condition: the attempt that brought all its frames (and only them: it
    logged ``logged`` frames), or, when they came from several (or that one asked for
    some places twice), a record of their own assembled from them."""
    sources = sorted({number for number, _ in kept.values()})
    if sources == [attempt] and logged == len(frames):
        writer.end(attempt, len(frames))
        return
    _close(writer, attempt, "its frames complete the condition with those kept from "
           f"attempt(s) {', '.join(map(str, sources))}: stored assembled, next")
    writer.assemble(record, frames, sources)


def _close(writer: RawLogWriter, attempt: int | None, reason: str) -> None:
    """Mark an open attempt abandoned (and flush), if one is open."""
    if attempt is not None:
        writer.abandon(attempt, reason)
