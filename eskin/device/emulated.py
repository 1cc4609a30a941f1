"""The board's own firmware under emulation, with the skin model as the rig around it.

``firmware/emulator/eskin_emulator`` (C, against simavr) runs the compiled firmware
``firmware/eskin/build/eskin.elf`` with its UART on a pseudo-terminal, follows the
multiplexer and stepper pins, and at the start of every scan of the 20 terminals asks
this process for the voltages the CAV424 puts out (``FRAME <steps>`` → ``VOLTS ...``).
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
import selectors
import subprocess
import tempfile
import threading
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from eskin.device.link import LinkError
from eskin.device.physics import Indenter, SkinModel, SkinParams, Trial

FIRMWARE_DIR = Path(__file__).resolve().parents[2] / "firmware"
FIRMWARE_ELF = FIRMWARE_DIR / "eskin" / "build" / "eskin.elf"
HARNESS = FIRMWARE_DIR / "emulator" / "build" / "eskin_emulator"
STEPS_PER_MM = 2560        # firmware/eskin/board.h
UNITS = 65535              # the harness's full scale (the supply): simavr keeps 16 bits


def cav424_volts(model: SkinModel, capacitance_pf: np.ndarray) -> np.ndarray:
    """The CAV424's output voltage, before the ADC: the first half of
    :meth:`SkinModel.to_counts` (``tests/test_firmware.py`` checks that they agree)."""
    p = model.params
    return p.cav424_offset_v + model.cav424_gain_v * (capacitance_pf - p.cav424_ref_pf) / (
        p.cav424_ref_pf)


class EmulatedRig:
    """The skin and clamp around the emulated firmware; the harness process runs both.

    Use :func:`emulated_board`, which starts and stops it.
    """

    def __init__(self, params: SkinParams, *, rest_length_mm: float, samples: int,
                 resets_at_frames: Sequence[int] = ()) -> None:
        if samples < 1:
            raise ValueError(f"samples must be ≥ 1, got {samples}")
        self.model = SkinModel(params)
        # A fault to survive: the board resets as its n-th scan (counted from 1) begins.
        self.resets_at_frames = set(resets_at_frames)
        self.resets = 0
        self._scans = 0
        self.rest_length_mm = rest_length_mm
        self.samples = samples
        self.frames_served = 0
        self._lock = threading.Lock()
        self._trial = Trial(self.model, [0])
        self._indenters: list[Indenter] = []
        self._block: list[np.ndarray] = []
        p = params
        self._half_step = p.supply_v / (2**p.adc_bits - 1) / 2

    # ------------------------------------------------------------ the bench's hands

    def place(self, trial: int, contacts: Sequence[tuple[int, int, float]]) -> None:
        """Start trial ``trial`` (its placements, drift and noise) with these weights on."""
        with self._lock:
            self._trial = Trial(self.model, [trial])
            self._indenters = [self._trial.place(x, y, newtons) for x, y, newtons in contacts]
            self._block = []

    # ------------------------------------------------------------ the harness's questions

    def volts(self, steps: int) -> list[int]:
        """One scan's 20 voltages in the harness's units, the clamp ``steps`` from rest."""
        with self._lock:
            if not self._block:
                stretch = 1.0 + steps / STEPS_PER_MM / self.rest_length_mm
                self._block = list(self._trial.sample_pf(self.samples, stretch, self._indenters))
            capacitance = self._block.pop(0)
            self.frames_served += 1
        supply = self.model.params.supply_v
        volts = cav424_volts(self.model, capacitance) + self._half_step
        return [int(u) for u in np.clip(np.rint(volts / supply * UNITS), 0, UNITS)]

    def serve(self, process: subprocess.Popen) -> None:
        """Answer the harness until it exits (a thread's body)."""
        for line in process.stdout:
            words = line.split()
            if words[:1] == ["FRAME"] and len(words) == 2:
                self._scans += 1
                if self._scans in self.resets_at_frames:
                    self.resets += 1
                    answer = "RESET\n"
                else:
                    answer = "VOLTS " + " ".join(map(str, self.volts(int(words[1])))) + "\n"
                try:
                    process.stdin.write(answer)
                    process.stdin.flush()
                except (BrokenPipeError, ValueError):  # the harness is gone
                    return


@contextlib.contextmanager
def emulated_board(params: SkinParams, *, rest_length_mm: float, samples: int,
                   resets_at_frames: Sequence[int] = (), start_timeout_s: float = 30.0
                   ) -> Iterator[tuple[str, EmulatedRig]]:
    """Run the firmware under simavr; yield its pty and the rig that places the weights."""
    for built in (FIRMWARE_ELF, HARNESS):
        if not built.exists():
            raise LinkError(f"{built} is missing: run `make firmware` first")
    rig = EmulatedRig(params, rest_length_mm=rest_length_mm, samples=samples,
                      resets_at_frames=resets_at_frames)
    scratch = tempfile.TemporaryDirectory(prefix="eskin-emulator-")
    errors = Path(scratch.name) / "emulator.err"
    with errors.open("w") as stderr:
        process = subprocess.Popen([str(HARNESS), str(FIRMWARE_ELF)], stdin=subprocess.PIPE,
                                   stdout=subprocess.PIPE, stderr=stderr, text=True, bufsize=1)
    try:
        with selectors.DefaultSelector() as selector:
            selector.register(process.stdout, selectors.EVENT_READ)
            if not selector.select(start_timeout_s):
                raise LinkError(f"the emulator did not start within {start_timeout_s} s")
        first = process.stdout.readline().split()
        if first[:1] != ["PTY"] or len(first) != 2:
            process.wait(timeout=5)
            raise LinkError(f"the emulator exited: {errors.read_text().strip()[-2000:]}")
        server = threading.Thread(target=rig.serve, args=(process,), daemon=True)
        server.start()
        yield first[1], rig
    finally:
        process.terminate()
        try:
            process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
        scratch.cleanup()
