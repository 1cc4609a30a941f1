"""One acquisition session: pick the source, connect, resume, run, log.

``simulated`` starts ``eskin device simulate`` in its own process on a
pseudo-terminal and talks to it through pyserial, exactly as to a board on
``/dev/ttyACM0``; ``serial`` opens the given port and prompts the operator.
"""

from __future__ import annotations

import contextlib
import json
import selectors
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from eskin import __version__
from eskin.acquisition.plan import ScenePlan
from eskin.acquisition.rawlog import RawLogWriter, read_log
from eskin.acquisition.runner import (
    AcquisitionReport,
    OperatorPlacer,
    Placer,
    SimulatedPlacer,
    acquire,
)
from eskin.device.link import LinkError, SerialLink
from eskin.device.physics import SkinParams

LOG_NAME = "acquisition.log"


@dataclass(frozen=True)
class RunningBoard:
    port: str
    process: subprocess.Popen


@contextlib.contextmanager
def simulated_board(sim: SkinParams, *, rest_length_mm: float, corrupt_fraction: float = 0.0,
                    frame_period_ms: int = 12, socket_port: int | None = None,
                    start_timeout_s: float = 30.0) -> Iterator[RunningBoard]:
    """Run the simulated board in a child process; yield its port and process."""
    config = {"sim": sim.as_dict(), "rest_length_mm": rest_length_mm,
              "corrupt_fraction": corrupt_fraction, "frame_period_ms": frame_period_ms}
    command = [sys.executable, "-m", "eskin", "device", "simulate",
               "--config-json", json.dumps(config)]
    if socket_port is not None:
        command += ["--socket", str(socket_port)]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               stdin=subprocess.DEVNULL, text=True)
    try:
        with selectors.DefaultSelector() as selector:
            selector.register(process.stdout, selectors.EVENT_READ)
            if not selector.select(start_timeout_s):
                raise LinkError(f"simulated board did not start within {start_timeout_s} s")
        port = process.stdout.readline().strip()
        if not port:
            raise LinkError(f"simulated board exited: {process.stderr.read().strip()}")
        yield RunningBoard(port, process)
    finally:
        process.terminate()
        try:
            process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def run_session(plan: ScenePlan, raw_dir: Path, *, port: str, placer: Placer,
                rest_length_mm: float, simulator: dict | None, timeout_s: float = 5.0,
                max_attempts: int = 5, progress: bool = True) -> AcquisitionReport:
    """Connect to the board on ``port`` and acquire what the raw log still lacks."""
    log_path = Path(raw_dir) / LOG_NAME
    contents = read_log(log_path) if log_path.exists() else None
    with SerialLink(port, timeout_s=timeout_s) as link:
        hello = link.connect()
        session = {
            "session": f"s{len(contents.sessions) + 1 if contents else 1:03d}",
            "scene": plan.name, "plan": plan.as_dict(), "eskin": __version__,
            "source": "simulated" if simulator else "serial",
            # The simulator's pty name changes from run to run; a real port is provenance.
            "port": "simulated board (pty)" if simulator else port,
            "device": {"id": hello.device_id, "firmware": hello.firmware,
                       "terminals": hello.terminals, "adc_bits": hello.adc_bits},
            "simulator": simulator, "rest_length_mm": rest_length_mm,
        }
        if simulator is None:
            # A real session's date is part of its record; a simulated one leaves it out so
            # that the same params give a byte-identical log, and the same DVC hashes.
            session["started_utc"] = datetime.now(UTC).isoformat(timespec="seconds")
        completed = set(contents.completed) if contents else set()
        writer = RawLogWriter(log_path, session, contents)
        try:
            return acquire(plan, link, writer, placer, completed=completed,
                           rest_length_mm=rest_length_mm, max_attempts=max_attempts,
                           progress=progress)
        finally:
            writer.close()


def acquire_scene(plan: ScenePlan, raw_dir: Path, *, source: str, sim: SkinParams,
                  rest_length_mm: float, port: str | None = None, corrupt_fraction: float = 0.0,
                  frame_period_ms: int = 12, timeout_s: float = 5.0, max_attempts: int = 5,
                  ask: Callable[[str], object] = input, progress: bool = True
                  ) -> AcquisitionReport:
    """Acquire a scene from the simulated board or from a real one on ``port``."""
    if source == "simulated":
        with simulated_board(sim, rest_length_mm=rest_length_mm,
                             corrupt_fraction=corrupt_fraction,
                             frame_period_ms=frame_period_ms) as board:
            return run_session(plan, raw_dir, port=board.port, placer=SimulatedPlacer(),
                               rest_length_mm=rest_length_mm,
                               simulator={"params": sim.as_dict(), "seed": sim.seed},
                               timeout_s=timeout_s, max_attempts=max_attempts,
                               progress=progress)
    if source == "serial":
        if not port:
            raise ValueError("acquire.source is 'serial' but acquire.port is not set")
        return run_session(plan, raw_dir, port=port, placer=OperatorPlacer(ask),
                           rest_length_mm=rest_length_mm, simulator=None, timeout_s=timeout_s,
                           max_attempts=max_attempts, progress=progress)
    raise ValueError(f"acquire.source must be 'simulated', 'serial' or 'import', got {source!r}")
