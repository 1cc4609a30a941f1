"""The board's own firmware under emulation, with the skin model as the rig around it.

``firmware/emulator/build/<R>x<C>/eskin_emulator`` (C, against simavr) runs the firmware
compiled for the skin's R rows and C columns, ``firmware/eskin/build/<R>x<C>/eskin.elf``,
with its UART on a pseudo-terminal, follows the multiplexer and stepper pins, and at the
start of every scan of the R + C terminals asks this process for the voltages the CAV424
puts out (``FRAME <steps>`` → ``VOLTS ...``).
:class:`EmulatedRig` answers from the same :class:`~eskin.device.physics.SkinModel`
and :class:`~eskin.device.physics.Trial` as the Python board, at the stretch the
firmware drove the clamp to (its step count). The host talks to the pty exactly as to a
board on ``/dev/ttyACM0``; the weights are placed through the rig (:meth:`EmulatedRig.
place`), as a person places them on a bench — the firmware knows nothing of them.

Two choices make the emulated firmware read what the Python board sends for the same
trial, which is what the equivalence test checks:

* a trial's frames are drawn in blocks of the scene's ``samples``, as the Python board
  draws a ``SAMPLE n``'s frames at once (the noise stream depends on the block size);
* the voltage is handed to simavr plus half an ADC step: simavr's ADC truncates
  (value × 1023 / Vref), while the ideal AVR ADC, and the physics model's ``rint``, put
  the first transition at half a step. simavr takes a voltage in 16 bits (5 V / 65535,
  76 µV, 1/64 of an ADC step): within that of a transition the two may differ by one
  count.
"""

from __future__ import annotations

import contextlib
import subprocess
import sys
import tempfile
import threading
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np

from eskin.device.firmware import build_name
from eskin.device.link import LinkError
from eskin.device.physics import Indenter, SkinModel, SkinParams, Trial
from eskin.device.process import child_board
from eskin.errors import EskinError
from eskin.skin import AnySkin

FIRMWARE_DIR = Path(__file__).resolve().parents[2] / "firmware"
# What the two are built from (with eskin/device/firmware.py, which writes the skin's
# header): the acquire stage lists these (a test checks), so editing the firmware
# reacquires an emulated scene, and emulated_board rebuilds before it runs.
FIRMWARE_SOURCES = tuple(Path("firmware") / name for name in (
    "eskin/eskin.ino", "eskin/board.h", "eskin/Makefile",
    "emulator/eskin_emulator.c", "emulator/Makefile"))
BUILD_TIMEOUT_S = 600.0
FAULTS = ("reset", "vanish")
EMULATED_ID = "emulated"  # the id acquisition gives the emulated board
STEPS_PER_MM = 2560        # firmware/eskin/board.h
UNITS = 65535              # the harness's full scale (the supply): simavr keeps 16 bits


def firmware_elf(skin: AnySkin) -> Path:
    """The firmware built for ``skin`` (``make ROWS=R COLUMNS=C`` in firmware/eskin)."""
    return FIRMWARE_DIR / "eskin" / "build" / build_name(skin) / "eskin.elf"


def harness(skin: AnySkin) -> Path:
    """The emulation harness built for ``skin``'s firmware."""
    return FIRMWARE_DIR / "emulator" / "build" / build_name(skin) / "eskin_emulator"


def cav424_volts(model: SkinModel, capacitance_pf: np.ndarray) -> np.ndarray:
    """The CAV424's output voltage, before the ADC: the first half of
    :meth:`SkinModel.to_counts` (``tests/test_firmware.py`` checks that they agree). Splitting
    it out of physics.py would now cost nothing: the simulated board's identity
    (:func:`~eskin.device.board.simulator_identity`) is what the board answers to a fixed
    probe, not physics.py's bytes, so a refactor that reads the same keeps every simulated
    dataset; only a change in the counts re-keys, and redraws, them all."""
    p = model.params
    return p.cav424_offset_v + model.cav424_gain_v * (capacitance_pf - p.cav424_ref_pf) / (
        p.cav424_ref_pf)


class EmulatedRig:
    """The skin and clamp around the emulated firmware; the harness process runs both.

    Use :func:`emulated_board`, which starts and stops it. ``faults`` maps a scan number
    (counted from 1) to a fault dealt as that scan begins: ``reset`` (the board resets
    mid-request) or ``vanish`` (the USB link drops for ``vanish_s`` and comes back on a new
    pty, the board reset as an Uno is when its port is opened). ``frame_period_ms`` is the
    board time between two scans as the skin model reads it (drift and creep): the Python
    board's, so that the two read the same trial alike (the firmware's own pace under
    simavr is the host's to bear, not the skin's).
    """

    def __init__(self, params: SkinParams, *, skin: AnySkin, rest_length_mm: float,
                 samples: int, faults: Mapping[int, str] | None = None,
                 vanish_s: float = 0.5, frame_period_ms: int = 12) -> None:
        if samples < 1:
            raise ValueError(f"samples must be ≥ 1, got {samples}")
        self.faults = dict(faults or {})
        unknown = set(self.faults.values()) - set(FAULTS)
        if unknown:
            raise ValueError(f"emulated faults must be {' or '.join(FAULTS)}, got {unknown}")
        self.vanish_ms = round(vanish_s * 1000)
        self.failure: str | None = None  # why the rig stopped answering, if it did
        self.model = SkinModel(params, skin)
        self.rest_length_mm = rest_length_mm
        self.samples = samples
        self._scans = 0
        self._lock = threading.Lock()
        self.frame_period_s = frame_period_ms / 1000
        self._trial = Trial(self.model, [0], frame_period_s=self.frame_period_s)
        self._indenters: list[Indenter] = []
        self._block: list[np.ndarray] = []
        self._replay_from = 0  # replay(): the scans of the next block to leave out
        self._pick: list[int] | None = None  # pick(): the scans of the next block to send
        self._half_step = params.supply_v / (2**params.adc_bits - 1) / 2

    # ------------------------------------------------------------ the bench's hands

    def place(self, trial: int, contacts: Sequence[tuple[int, int, float]]) -> None:
        """Start trial ``trial`` (its placements, drift and noise) with these weights on."""
        with self._lock:
            self._trial = Trial(self.model, [trial], frame_period_s=self.frame_period_s)
            self._indenters = [self._trial.place(x, y, newtons) for x, y, newtons in contacts]
            self._block = []
            self._replay_from = 0
            self._pick = None

    def replay(self, first: int) -> None:
        """Rewind the trial, the weights left where they lie: the scans from now on read
        as its first block's from its scan ``first`` on (as the Python board's ``SIM
        REPLAY``)."""
        with self._lock:
            self._trial.rewind()
            self._block = []
            self._replay_from = first
            self._pick = None

    def pick(self, places: Sequence[int]) -> None:
        """Rewind the trial, the weights left where they lie: the scans from now on read as
        its first block's scans ``places``, in that order (as the Python board's ``SIM
        PICK``), then as blocks after it."""
        with self._lock:
            self._trial.rewind()
            self._block = []
            self._replay_from = 0
            self._pick = list(places)

    # ------------------------------------------------------------ the harness's questions

    def volts(self, steps: int) -> list[int]:
        """One scan's voltages (one per terminal) in the harness's units, the clamp
        ``steps`` from rest."""
        with self._lock:
            if not self._block:
                stretch = 1.0 + steps / STEPS_PER_MM / self.rest_length_mm
                block = self._trial.sample_pf(self.samples, stretch, self._indenters)
                self._block = (list(block[self._replay_from:]) if self._pick is None
                               else [block[place] for place in self._pick])
                self._replay_from, self._pick = 0, None
            capacitance = self._block.pop(0)
        supply = self.model.params.supply_v
        volts = cav424_volts(self.model, capacitance) + self._half_step
        return [int(u) for u in np.clip(np.rint(volts / supply * UNITS), 0, UNITS)]

    def answer(self, question: str) -> str:
        """The harness's one question, ``FRAME <steps>``, answered."""
        words = question.split()
        if words[:1] != ["FRAME"] or len(words) != 2:
            raise ValueError(f"the harness asked {question.strip()!r}, not FRAME <steps>")
        self._scans += 1
        fault = self.faults.get(self._scans)
        if fault is not None:
            return "RESET\n" if fault == "reset" else f"VANISH {self.vanish_ms}\n"
        return "VOLTS " + " ".join(map(str, self.volts(int(words[1])))) + "\n"

    def serve(self, process: subprocess.Popen) -> None:
        """Answer the harness until it exits (a thread's body). If the rig fails, it says
        why in ``failure`` and closes the harness's stdin, which ends it: the host then
        loses the port, and :func:`emulated_board` puts the failure in its error."""
        try:
            for line in process.stdout:
                process.stdin.write(self.answer(line))
                process.stdin.flush()
        except Exception as err:  # noqa: BLE001 (a thread's end: kept for the host's error)
            if process.poll() is None:  # not merely the harness gone at the end
                self.failure = f"{type(err).__name__}: {err}"
                with contextlib.suppress(OSError):
                    process.stdin.close()


def build_firmware(skin: AnySkin, timeout_s: float = BUILD_TIMEOUT_S) -> None:
    """Bring the firmware for ``skin`` and its harness up to date with their sources (make;
    a no-op when they are), so what is emulated is what the sources say."""
    size = build_name(skin)  # a skin the firmware cannot read fails here, in one line
    rows, columns = size.split("x")
    for directory in (FIRMWARE_DIR / "eskin", FIRMWARE_DIR / "emulator"):
        command = ["make", "-s", "-C", str(directory), f"ROWS={rows}", f"COLUMNS={columns}",
                   f"PYTHON={sys.executable}"]
        try:
            done = subprocess.run(command, capture_output=True, text=True, timeout=timeout_s,
                                  check=False)
        except FileNotFoundError:
            raise LinkError("building the firmware needs make (`make avr` installs the AVR "
                            "toolchain and simavr)") from None
        except subprocess.TimeoutExpired:
            raise LinkError(f"building {directory} took over {timeout_s:g} s") from None
        if done.returncode != 0:
            said = (done.stderr or done.stdout).strip().splitlines()[-1:] or ["(no output)"]
            raise LinkError(f"building {directory} for the {size} skin failed (`make avr` "
                            f"installs the AVR toolchain and simavr): {said[0]}")


@contextlib.contextmanager
def emulated_board(params: SkinParams, *, skin: AnySkin, rest_length_mm: float,
                   samples: int, faults: Mapping[int, str] | None = None,
                   vanish_s: float = 0.5, frame_period_ms: int = 12,
                   start_timeout_s: float = 30.0
                   ) -> Iterator[tuple[str, EmulatedRig]]:
    """Build the firmware for ``skin`` and run it under simavr; yield its port (a link that
    follows its pty) and the rig that places the weights."""
    rig = EmulatedRig(params, skin=skin, rest_length_mm=rest_length_mm, samples=samples,
                      faults=faults, vanish_s=vanish_s, frame_period_ms=frame_period_ms)
    build_firmware(skin)
    with tempfile.TemporaryDirectory(prefix="eskin-emulator-") as scratch, child_board(
            [str(harness(skin)), str(firmware_elf(skin)), str(Path(scratch) / "tty")],
            name="the emulated board", workdir=Path(scratch), stdin=subprocess.PIPE,
            start_timeout_s=start_timeout_s) as child:
        words = child.first_line.split()
        if words[:1] != ["PTY"] or len(words) != 2:
            raise LinkError(f"the emulated board began {child.first_line!r}, not PTY <path>")
        server = threading.Thread(target=rig.serve, args=(child.process,), daemon=True)
        server.start()
        try:
            yield words[1], rig
        except EskinError as err:
            if rig.failure is not None:
                raise LinkError(f"{err}\nThe emulated rig had failed: {rig.failure}") from err
            raise
