"""The acquisition runner: walks a scene's plan over a serial link into a raw log.

For each condition not yet recorded on this device it sets the stretch,
has the indenters placed — by ``SIM`` commands on the simulated board, by a
person prompted at the terminal on a real one — and asks for the samples. A
condition is stored only whole: if any frame fails its CRC, is malformed or
is missing from the sequence, or a reading jumps far from the rest of its
condition (a damaged frame whose CRC-8 matched by chance), the attempt is
logged as abandoned and the condition is asked again (the simulated board
replays the same trial, so a faulty link still gives the clean run's data).
A board that restarts mid-condition (``#HELLO``) gets its stretch and
indenters again; a port that fails is reopened with backoff, and only the
same board is accepted back.
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from tqdm import tqdm

from eskin.acquisition.plan import Condition, ScenePlan
from eskin.acquisition.rawlog import RawLogWriter
from eskin.device.link import (
    BoardRefused,
    BoardReset,
    DeviceChanged,
    LinkError,
    ProtocolViolation,
    SampleBatch,
    SerialLink,
    jump_problem,
)
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
    resets: int = 0        # the board restarted mid-condition
    reconnects: int = 0    # the link failed and was reopened

    @property
    def frames_per_s(self) -> float:
        return self.frames_stored / self.seconds if self.seconds > 0 else 0.0

    def summary(self) -> str:
        return (f"{self.scene}: {self.acquired} condition(s) acquired, {self.reused} reused "
                f"of {self.conditions}; {self.frames_stored} frames stored, "
                f"{self.frames_rejected} rejected, {self.retries} retried condition(s), "
                f"{self.resets} board restart(s), {self.reconnects} reconnect(s); "
                f"{self.seconds:.1f} s ({self.frames_per_s:.0f} frames/s over {self.port})")


def trial_seed(key: str) -> int:
    """The simulated board's trial number for a condition key (60 bits)."""
    return int(key[:15], 16)


class Placer(Protocol):
    def place(self, link: SerialLink, condition: Condition, key: str, repeat: bool) -> None: ...


class SimulatedPlacer:
    """Places indenters on the simulated board with SIM commands."""

    def place(self, link: SerialLink, condition: Condition, key: str, repeat: bool) -> None:
        link.command("SIM CLEAR")
        link.command(f"SIM TRIAL {trial_seed(key)}")
        for contact in condition.contacts:
            if contact.touches:
                link.command(f"SIM PRESS {contact.x} {contact.y} {contact.force!r}")


class EmulatedPlacer:
    """Places the weights on the emulated rig (:mod:`eskin.device.emulated`), as a person
    does on a bench: the firmware knows nothing of them. Each condition's trial is the one
    the Python board draws for it (its key on that board), so that an emulated and a
    simulated acquisition of the same plan compare sample by sample."""

    def __init__(self, rig, simulated_id: str, simulated_firmware: str) -> None:
        self.rig = rig
        self.simulated = (simulated_id, simulated_firmware)

    def place(self, link: SerialLink, condition: Condition, key: str, repeat: bool) -> None:
        self.rig.place(trial_seed(condition.key(*self.simulated)),
                       [(c.x, c.y, c.force) for c in condition.contacts if c.touches])


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
            reconnect_s: float = 30.0, max_jump_counts: float = 40.0,
            progress: bool = True,
            notify: Callable[[str], object] | None = None) -> AcquisitionReport:
    """Acquire every condition of ``plan`` not yet recorded whole: its key is not in
    ``completed`` (key -> frames of its latest complete attempt), or with fewer frames
    than the plan's samples (a plan whose ``samples`` grew).

    A damaged batch is asked again; a board that restarts gets its stretch and
    indenters again; a link that fails (the port vanishes, the board falls
    silent past the timeout) is reopened with backoff for up to
    ``reconnect_s``. Every frame that arrived, in whole attempts or not, is in
    the log before any error or Ctrl-C leaves this function.
    """
    hello = link.hello
    if hello is None:
        raise AcquisitionError(f"no #HELLO from the board on {link.port}: call connect() first")
    started = time.monotonic()
    report = AcquisitionReport(plan.name, link.port, len(plan.conditions), 0, 0, 0, 0, 0, 0.0)
    stretch_mm: str | None = None
    bar = tqdm(total=len(plan.conditions), desc=f"acquire {plan.name}", unit="cond",
               disable=not progress, leave=False)
    say = notify or (lambda message: tqdm.write(f"acquire {plan.name}: {message}",
                                                file=sys.stderr))
    with bar:
        for condition in plan.conditions:
            key = condition.key(hello.device_id, hello.firmware)
            if completed.get(key, 0) >= plan.samples:
                report.reused += 1
                bar.update()
                continue
            wanted_mm = f"{(condition.stretch - 1.0) * rest_length_mm:.3f}"
            record = {"key": key, "scene": plan.name, **condition.as_dict()}
            problem = None
            for attempt_no in range(max_attempts):
                attempt = None
                try:
                    if wanted_mm != stretch_mm:
                        link.command(f"STRETCH {wanted_mm}")
                        stretch_mm = wanted_mm
                    placer.place(link, condition, key, repeat=attempt_no > 0)
                    attempt = writer.begin(record)
                    batch = SampleBatch(plan.samples)
                    try:
                        link.sample(batch)
                    finally:  # an error or Ctrl-C mid-batch: what arrived is kept
                        writer.frames(attempt, batch.frames)
                        writer.rejected(attempt, batch.rejected)
                        report.frames_rejected += batch.rejected_count
                    problem = batch.problem or jump_problem(batch, max_jump_counts)
                except BoardRefused:
                    _close(writer, attempt, "the board refused a command")
                    raise
                except DeviceChanged as err:
                    _close(writer, attempt, "another board answered")
                    raise AcquisitionError(
                        f"{plan.name}: {err}. Nothing from it was stored; everything the "
                        f"session's board sent is in {writer.path}.") from err
                except ProtocolViolation as err:
                    problem = str(err)  # the next request is fenced; ask again
                except BoardReset as err:
                    problem = str(err)
                    report.resets += 1
                    stretch_mm = None  # a restarted board forgot where the clamp is
                except LinkError as err:
                    problem = str(err)
                    _close(writer, attempt, problem)
                    attempt = None
                    report.reconnects += 1
                    stretch_mm = None
                    try:
                        link.reopen(budget_s=reconnect_s, notify=say)
                    except LinkError as lost:
                        raise AcquisitionError(
                            f"{plan.name}: {lost}. Everything received is in {writer.path}; "
                            "rerun to resume.") from lost
                except BaseException:  # Ctrl-C, or a bug: the attempt is closed, then stop
                    _close(writer, attempt, "interrupted")
                    raise
                if problem is None:
                    writer.end(attempt, len(batch.frames))
                    report.frames_stored += len(batch.frames)
                    break
                _close(writer, attempt, problem)
                report.retries += 1
                log.info("%s: %s; asking again", condition.describe(), problem)
            else:
                raise AcquisitionError(
                    f"{plan.name}: {condition.describe()} failed {max_attempts} times on "
                    f"{link.port}, last: {problem}. Received data is in {writer.path}; "
                    "rerun to resume.")
            completed[key] = len(batch.frames)
            report.acquired += 1
            bar.update()
    report.seconds = time.monotonic() - started
    return report


def _close(writer: RawLogWriter, attempt: int | None, reason: str) -> None:
    """Mark an open attempt abandoned (and flush), if one is open."""
    if attempt is not None:
        writer.abandon(attempt, reason)
