"""One acquisition session: pick the source, connect, resume, run, log.

``simulated`` starts the simulated board (``python -m eskin.device.simulate``) in its
own process on a pseudo-terminal and talks to it through pyserial, exactly as to a
board on ``/dev/ttyACM0``; ``emulated`` does the same with the board's own firmware
under simavr (:mod:`eskin.device.emulated`); ``serial`` opens the given port and prompts
the operator.
"""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from eskin import __version__
from eskin.acquisition.runner import (
    AcquisitionError,
    AcquisitionReport,
    EmulatedPlacer,
    OperatorPlacer,
    Placer,
    SimulatedPlacer,
    acquire,
)
from eskin.data.plan import ScenePlan
from eskin.data.rawlog import (
    LOG_NAME,
    LogContents,
    RawLogWriter,
    acquisition_sessions,
    read_log_if_any,
)
from eskin.device.faults import LinkFaults
from eskin.device.link import SerialLink, SkinMismatch, set_device_id
from eskin.device.physics import SkinParams
from eskin.device.process import child_board
from eskin.device.protocol import UNSET_ID, Hello
from eskin.skin import PAPER_SKIN, AnySkin


@dataclass(frozen=True)
class RunningBoard:
    port: str
    process: subprocess.Popen


@contextlib.contextmanager
def simulated_board(sim: SkinParams, *, skin: AnySkin = PAPER_SKIN, rest_length_mm: float,
                    corrupt_fraction: float = 0.0, frame_period_ms: int = 12,
                    faults: LinkFaults | None = None, socket_port: int | None = None,
                    start_timeout_s: float = 30.0) -> Iterator[RunningBoard]:
    """Run the simulated board of ``skin`` in a child process; yield its port and process.

    On a pty the port is a symlink that follows the board's pty, so a link that
    vanishes and comes back (a ``vanish`` fault) is found again at the same path.
    """
    config = {"sim": sim.as_dict(), "skin": skin.as_dict(), "rest_length_mm": rest_length_mm,
              "corrupt_fraction": corrupt_fraction, "frame_period_ms": frame_period_ms,
              "faults": (faults or LinkFaults()).as_dict()}
    with tempfile.TemporaryDirectory(prefix="eskin-board-") as scratch:
        command = [sys.executable, "-m", "eskin.device.simulate",
                   "--config-json", json.dumps(config)]
        command += (["--socket", str(socket_port)] if socket_port is not None
                    else ["--link", str(Path(scratch) / "tty")])
        with child_board(command, name="the simulated board", workdir=Path(scratch),
                         start_timeout_s=start_timeout_s) as child:
            yield RunningBoard(child.first_line, child.process)


def session_id(contents: LogContents | None, plan: ScenePlan, hello: Hello) -> str:
    """The id of the session about to start: ``s<n>``, counted per device.

    A run that resumes an interrupted session (the log's last session is on the
    same device, for the same plan, and left conditions undone) continues it
    under its id, so a crash and a resume label the data as a clean run does;
    and a device's sessions are numbered the same whatever else the log holds
    (another simulator seed, say), so a fresh clone gets the same labels.
    """
    sessions = acquisition_sessions(contents) if contents is not None else []
    if not sessions:
        return "s001"
    last, device_id = sessions[-1], hello.device_id
    keys = {c.key(device_id, hello.firmware) for c in plan.conditions}
    whole = {key for key, attempt in contents.completed.items()
             if len(attempt.frames) >= plan.samples}
    if (last["device"]["id"] == device_id and last.get("plan") == plan.as_dict()
            and not keys <= whole):
        return last["session"]
    ids = {s["session"] for s in sessions if s["device"]["id"] == device_id}
    return f"s{len(ids) + 1:03d}"


def run_session(plan: ScenePlan, raw_dir: Path, *, port: str, placer: Placer,
                rest_length_mm: float, simulator: dict | None, timeout_s: float = 5.0,
                max_attempts: int = 5, max_interruptions: int = 20,
                reconnect_s: float = 30.0, max_jump_counts: float = 40.0,
                progress: bool = True) -> AcquisitionReport:
    """Connect to the board on ``port`` and acquire what the raw log still lacks."""
    source = ("emulated" if simulator and simulator.get("emulated") else
              "simulated" if simulator else "serial")
    log_path = Path(raw_dir) / LOG_NAME
    contents = read_log_if_any(log_path)
    with SerialLink(port, terminals=plan.skin.terminals, timeout_s=timeout_s) as link:
        try:
            hello = link.connect()
        except SkinMismatch as err:  # before the log is touched: nothing is lost
            raise AcquisitionError(
                f"{plan.name}: the board on {port} has {err.hello.terminals} terminals "
                f"(terminals={err.hello.terminals} in its #HELLO), but the scene's skin is the "
                f"{plan.skin.describe()}: set scenes.{plan.name}.skin to the board's rows "
                f"and columns ({{rows: R, columns: C}} with R + C = {err.hello.terminals}), "
                "or connect the board built for this skin; nothing was recorded") from None
        if hello.device_id == UNSET_ID and simulator is None:
            # Its data would be filed under an id that any other new board shares.
            raise AcquisitionError(f"the board on {port} has no device id (id={UNSET_ID}): "
                                   f"give it one, once: eskin device set-id {port} <id>")
        session = {
            "session": session_id(contents, plan, hello),
            "scene": plan.name, "plan": plan.as_dict(), "eskin": __version__,
            "source": source,
            # The simulator's pty name changes from run to run; a real port is provenance.
            "port": f"{source} board (pty)" if simulator else port,
            "device": {"id": hello.device_id, "firmware": hello.firmware,
                       "terminals": hello.terminals, "adc_bits": hello.adc_bits},
            "simulator": simulator, "rest_length_mm": rest_length_mm,
        }
        if simulator is None:
            # A real session's date is part of its record; a simulated one leaves it out so
            # that the same params give a byte-identical log, and the same DVC hashes.
            session["started_utc"] = datetime.now(UTC).isoformat(timespec="seconds")
        completed = ({key: len(attempt.frames) for key, attempt in contents.completed.items()}
                     if contents else {})
        writer = RawLogWriter(log_path, session, contents)
        try:
            return acquire(plan, link, writer, placer, completed=completed,
                           rest_length_mm=rest_length_mm, max_attempts=max_attempts,
                           max_interruptions=max_interruptions, reconnect_s=reconnect_s,
                           max_jump_counts=max_jump_counts, progress=progress)
        finally:
            writer.close()


def acquire_scene(plan: ScenePlan, raw_dir: Path, *, source: str, sim: SkinParams,
                  rest_length_mm: float, port: str | None = None, corrupt_fraction: float = 0.0,
                  faults: LinkFaults | None = None, frame_period_ms: int = 12,
                  timeout_s: float = 5.0, max_attempts: int = 5,
                  max_interruptions: int = 20, reconnect_s: float = 30.0,
                  max_jump_counts: float = 40.0, ask: Callable[[str], object] = input,
                  indenters: str = "person", progress: bool = True,
                  emulated_faults: Mapping[int, str] | None = None) -> AcquisitionReport:
    """Acquire a scene from the simulated board or from a board on ``port``.

    ``indenters``: on a board on a port, who places the weights — a ``person``
    prompted at the terminal (a real rig), or the ``board`` itself through ``SIM``
    commands (a simulated board served on a port). ``emulated_faults``: link faults the
    emulated board is dealt as these scans begin (counted from 1), ``reset`` or ``vanish``
    (for ``faults.vanish_s``); see :class:`~eskin.device.emulated.EmulatedRig`.
    """
    options = {"rest_length_mm": rest_length_mm, "timeout_s": timeout_s,
               "max_attempts": max_attempts, "max_interruptions": max_interruptions,
               "reconnect_s": reconnect_s,
               "max_jump_counts": max_jump_counts, "progress": progress}
    if source == "simulated":
        with simulated_board(sim, skin=plan.skin, rest_length_mm=rest_length_mm,
                             corrupt_fraction=corrupt_fraction, faults=faults,
                             frame_period_ms=frame_period_ms) as board:
            return run_session(plan, raw_dir, port=board.port, placer=SimulatedPlacer(),
                               simulator={"params": sim.as_dict(), "seed": sim.seed},
                               **options)
    if source == "emulated":
        # The board's firmware under simavr (make firmware), the skin model around it.
        from eskin.device.board import FIRMWARE, simulator_identity
        from eskin.device.emulated import EMULATED_ID, emulated_board

        with emulated_board(sim, skin=plan.skin, rest_length_mm=rest_length_mm,
                            samples=plan.samples, faults=emulated_faults,
                            vanish_s=(faults or LinkFaults()).vanish_s,
                            frame_period_ms=frame_period_ms) as (emulated_port, rig):
            # Its EEPROM starts erased in every run: it is given its id, as a new board is.
            set_device_id(emulated_port, EMULATED_ID, timeout_s=timeout_s)
            placer = EmulatedPlacer(rig, simulator_identity(sim, rest_length_mm, plan.skin),
                                    FIRMWARE)
            return run_session(plan, raw_dir, port=emulated_port, placer=placer,
                               simulator={"params": sim.as_dict(), "seed": sim.seed,
                                          "emulated": True}, **options)
    if source == "serial":
        if not port:
            raise ValueError("source is 'serial' but no port is set (scenes.<scene>.port)")
        placer = SimulatedPlacer() if indenters == "board" else OperatorPlacer(ask)
        return run_session(plan, raw_dir, port=port, placer=placer, simulator=None, **options)
    raise ValueError(f"source must be 'simulated', 'emulated' or 'serial' here, got {source!r}")
