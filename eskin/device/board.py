"""The simulated board's command handling, as pure code (bytes in, bytes out).

It speaks wire protocol v1 exactly as the firmware does, plus the simulated-
board commands ``SIM PRESS <x> <y> <newtons> [<ramp_ms>]``, ``SIM CLEAR``, ``SIM TRIAL
<n>``, ``SIM WAIT <ms>``, ``SIM REPLAY <from>`` and ``SIM PICK <n> <i> <j> ...``.
``SIM TRIAL`` starts trial n: placements, noise and its start in board time come from
streams seeded by (sim seed, n), drift and creep from the skin in board time. ``SIM
REPLAY`` rewinds the trial, its weights left where they lie, so that the next ``SAMPLE
k`` answers frames from .. from + k - 1 of the trial's first (from + k)-frame answer:
the frames an answer lost on the line are asked again and read as they did, and a run
with link faults gives the same dataset as a clean one. ``SIM PICK n i j ...`` does
the same for places that are not one run: the next ``SAMPLE k`` (k places named)
answers samples i, j, ... of a first n-frame answer, so a top-up asks only for the
places missing. Transports live in ``simulate.py``.
"""

from __future__ import annotations

import functools
import hashlib
import json

import numpy as np

from eskin import __version__
from eskin.device.physics import Indenter, SkinModel, SkinParams, Trial
from eskin.device.protocol import MAX_LINE_BYTES, SEQ_MAX, encode_frame
from eskin.skin import PAPER_SKIN, AnySkin, Skin, skin_from_dict

MAX_EXTENSION_MM = 40.0
MAX_NEWTONS = 50.0
MAX_SAMPLE = 100_000
MAX_RAMP_MS = 10_000
MAX_WAIT_MS = 3_600_000
STEPPER_MS = 500  # board time a STRETCH takes
FIRMWARE = f"sim-{__version__}"


# The fixed questions whose answers are the simulated board's identity: each thing that
# shapes a reading at least once — the rest reading with its drift and noise, stretches
# beyond rest (through the rig's rest length), a seated weight on a node, a light one not
# seated (its placement and tilt), two at once (one at an edge, one heavy), two on
# neighbouring nodes (saturating), three on one row at full stretch (the CAV424 clipped to
# its supply), a ramped press held a minute and released, and a new trial's stream for
# each. 124 frames, 2480 readings: a shift of a hundredth of an ADC count in every reading
# moves about twenty of them. HELLO is left out: its line carries the identity itself.
# Written for the paper's 10 × 10 skin; on another, a press beyond its last row or column
# lands on that row or column (probe()).
PROBE = (
    "STRETCH 0", "SIM TRIAL 1", "SAMPLE 16",
    "SIM TRIAL 2", "SIM PRESS 6 6 5.2136", "SAMPLE 16",
    "SIM CLEAR", "SIM TRIAL 3", "SIM PRESS 4 7 1.2936", "SAMPLE 16",
    "SIM CLEAR", "STRETCH 8", "SIM TRIAL 4", "SAMPLE 16",
    "SIM PRESS 1 1 3.2536", "SIM PRESS 10 6 20", "SAMPLE 16",
    "SIM CLEAR", "STRETCH 16", "SIM TRIAL 5", "SIM PRESS 6 6 5.2136", "SIM PRESS 6 7 50",
    "SAMPLE 16",
    "SIM CLEAR", "STRETCH 40", "SIM TRIAL 6", "SIM PRESS 2 6 50", "SIM PRESS 5 6 50",
    "SIM PRESS 8 6 50", "SAMPLE 4",
    # in board time: a hand press's ramp, creep under a minute's load, relaxation after it
    "SIM CLEAR", "STRETCH 0", "SIM TRIAL 7", "SIM PRESS 5 5 5.2136 200", "SAMPLE 8",
    "SIM WAIT 60000", "SAMPLE 8", "SIM CLEAR", "SIM WAIT 5000", "SAMPLE 8",
)
# Fixed: the link's timing (sim_board) is not the skin's. A board's frame period decides
# when within the drift its frames fall, as a real board's does; it is the same skin, and
# the same device, whatever its rate.
PROBE_FRAME_PERIOD_MS = 12


def probe(skin: Skin) -> tuple[str, ...]:
    """:data:`PROBE` on ``skin``: each press's row and column at most the skin's last."""
    def on_skin(command: str) -> str:
        if not command.startswith("SIM PRESS "):
            return command
        x, y, *load = command.split()[2:]
        return f"SIM PRESS {min(int(x), skin.rows)} {min(int(y), skin.columns)} {' '.join(load)}"

    return tuple(on_skin(command) for command in PROBE)


def simulator_identity(params: SkinParams, rest_length_mm: float,
                       skin: AnySkin = PAPER_SKIN) -> str:
    """A device id that changes whenever the simulated skin would read differently.

    It hashes the settings (every parameter, the seed, the rig's rest length, the skin's
    size when it is not the paper's) with what a fresh board built from them answers to
    :func:`probe`, byte for byte: so a change in the simulator's behaviour re-keys, and
    redraws, every simulated dataset, while a comment, a docstring or a refactor that
    reads the same keeps them. Computed once per settings in a process (a board is built
    again after every injected reset).
    """
    settings = {**params.as_dict(), "rest_length_mm": float(rest_length_mm)}
    if skin != PAPER_SKIN:  # the paper's skin keeps the ids its datasets were keyed by
        settings["skin"] = skin.as_dict()
    return _identity(json.dumps(settings, sort_keys=True))


@functools.lru_cache(maxsize=64)
def _identity(settings: str) -> str:
    """Keyed on the settings' canonical text, so that 3 and 3.0 are not confused."""
    values = json.loads(settings)
    rest_length_mm = values.pop("rest_length_mm")
    skin = skin_from_dict(values.pop("skin", None))
    digest = hashlib.sha256(settings.encode() + b"\n")
    digest.update(probe_answers(SkinParams(**values), rest_length_mm, skin))
    return f"sim-{digest.hexdigest()[:12]}"


def probe_answers(params: SkinParams, rest_length_mm: float,
                  skin: AnySkin = PAPER_SKIN) -> bytes:
    """What a fresh board with these settings answers to :func:`probe`."""
    board = SimulatedBoard(params, skin=skin, rest_length_mm=rest_length_mm,
                           frame_period_ms=PROBE_FRAME_PERIOD_MS)
    return b"".join(board.handle(command.encode()) for command in probe(board.skin))


class SimulatedBoard:
    """Protocol v1 state machine of a simulated e-skin board.

    Parameters
    ----------
    params
        The skin's physics and read-out parameters.
    skin
        Its rows and columns: a frame carries ``skin.terminals`` readings, and ``SIM
        PRESS`` takes nodes on it only.
    rest_length_mm
        Unstretched length between the clamps; ``STRETCH <mm>`` gives λ = 1 + mm / this.
    corrupt_fraction
        Share of frames damaged on the wire (a flipped byte or a truncated
        line), drawn from their own seeded stream, to exercise integrity checks.
    frame_period_ms
        Board time between frames (multiplexing the terminals and converting).
    """

    def __init__(self, params: SkinParams, *, skin: AnySkin = PAPER_SKIN,
                 rest_length_mm: float = 101.0, corrupt_fraction: float = 0.0,
                 frame_period_ms: int = 12) -> None:
        if not 0.0 <= corrupt_fraction < 1.0:
            raise ValueError(f"corrupt_fraction must be in [0, 1), got {corrupt_fraction}")
        if rest_length_mm <= 0:
            raise ValueError(f"rest_length_mm must be positive, got {rest_length_mm}")
        self.model = SkinModel(params, skin)
        self.skin = skin
        self.rest_length_mm = rest_length_mm
        self.corrupt_fraction = corrupt_fraction
        self.frame_period_ms = frame_period_ms
        self.streaming = False
        self.frames_corrupted = 0
        self._corrupt_rng = np.random.default_rng([params.seed, 2])
        self._seq = 0
        self._t_ms = 0
        self._stretch = 1.0
        self._trial = Trial(self.model, [0], frame_period_s=frame_period_ms / 1000)
        self._indenters: list[Indenter] = []
        self._replay_from = 0  # SIM REPLAY: the frames of the next answer to leave out
        self._pick: tuple[int, list[int]] | None = None  # SIM PICK: (of n frames, which)

    @functools.cached_property
    def device_id(self) -> str:
        """Worked out at the first HELLO: the probe's own board never asks for it."""
        return simulator_identity(self.model.params, self.rest_length_mm, self.skin)

    # ------------------------------------------------------------ output

    def hello(self) -> bytes:
        return (f"#HELLO eskin {FIRMWARE} terminals={self.skin.terminals} "
                f"adc_bits={self.model.params.adc_bits} id={self.device_id}\n").encode()

    def frames(self, n: int) -> bytes:
        """The next n frames at the current stretch and indenters (after ``SIM REPLAY
        <from>``, frames from .. from + n - 1 of a (from + n)-frame answer)."""
        skip, self._replay_from = self._replay_from, 0
        pick, self._pick = self._pick, None
        if pick is not None:  # SIM PICK: those of a first answer of pick[0] frames
            total, places = pick
            if n != len(places):
                raise ValueError(f"SIM PICK named {len(places)} sample(s), not {n}")
            counts = self._trial.sample_counts(total, self._stretch, self._indenters)[places]
        else:
            counts = self._trial.sample_counts(skip + n, self._stretch,
                                               self._indenters)[skip:]
        lines = []
        for row in counts:
            lines.append(self._wire(encode_frame(self._seq, self._t_ms, row)))
            self._seq = (self._seq + 1) & SEQ_MAX
            self._t_ms = (self._t_ms + self.frame_period_ms) & SEQ_MAX
        return b"".join(lines)

    def _wire(self, line: bytes) -> bytes:
        if not self.corrupt_fraction or self._corrupt_rng.random() >= self.corrupt_fraction:
            return line
        self.frames_corrupted += 1
        at = int(self._corrupt_rng.integers(0, len(line) - 1))
        if self._corrupt_rng.random() < 0.5:  # truncated line
            return line[:at] + b"\n"
        flipped = line[at] ^ int(self._corrupt_rng.integers(1, 256))
        if flipped == ord("\n"):  # keep one line one line; the CRC still catches it
            flipped ^= 0x80
        return line[:at] + bytes([flipped]) + line[at + 1:]

    # ------------------------------------------------------------ input

    def handle(self, line: bytes) -> bytes:
        """Answer one command line (without newline)."""
        text = line.strip().decode("ascii", errors="replace")
        if not text:
            return b""
        if len(line) > MAX_LINE_BYTES:
            return b"#ERR ? line too long\n"
        words = text.split()
        name = words[0].upper()
        try:
            if name == "HELLO" and len(words) == 1:
                return self.hello()
            if name == "STRETCH" and len(words) == 2:
                return self._stretch_to(words[1])
            if name == "SAMPLE" and len(words) == 2:
                n = _number(words[1], int, 1, MAX_SAMPLE)
                return self.frames(n) + b"#OK SAMPLE %d\n" % n
            if name == "STREAM" and len(words) == 2 and words[1].upper() in ("ON", "OFF"):
                self.streaming = words[1].upper() == "ON"
                return f"#OK STREAM {words[1].upper()}\n".encode()
            if name == "SIM" and len(words) >= 2:
                return self._sim(words[1].upper(), words[2:])
        except ValueError as err:
            return f"#ERR {name} {err}\n".encode()
        return f"#ERR {name} unknown command or wrong arguments\n".encode()

    def _stretch_to(self, text: str) -> bytes:
        mm = _number(text, float, 0.0, MAX_EXTENSION_MM)
        self._stretch = 1.0 + mm / self.rest_length_mm
        self._t_ms = (self._t_ms + STEPPER_MS) & SEQ_MAX  # the stepper takes its time
        self._trial.wait(STEPPER_MS / 1000, self._stretch, self._indenters)
        return f"#OK STRETCH {text}\n".encode()

    def _sim(self, sub: str, args: list[str]) -> bytes:
        if sub == "CLEAR" and not args:
            self._indenters = []
            return b"#OK SIM CLEAR\n"
        if sub == "TRIAL" and len(args) == 1:
            n = _number(args[0], int, 0, 2**63 - 1)
            self._trial = Trial(self.model, [n], frame_period_s=self.frame_period_ms / 1000)
            self._replay_from, self._pick = 0, None
            return f"#OK SIM TRIAL {n}\n".encode()
        if sub == "WAIT" and len(args) == 1:  # board time passes unread: drift, creep
            ms = _number(args[0], int, 0, MAX_WAIT_MS)
            self._trial.wait(ms / 1000, self._stretch, self._indenters)
            self._t_ms = (self._t_ms + ms) & SEQ_MAX
            return f"#OK SIM WAIT {ms}\n".encode()
        if sub == "REPLAY" and len(args) == 1:
            self._replay_from, self._pick = _number(args[0], int, 0, MAX_SAMPLE), None
            self._trial.rewind()
            return f"#OK SIM REPLAY {self._replay_from}\n".encode()
        if sub == "PICK" and len(args) >= 2:
            # The top-up of places that are not one run: SIM REPLAY i can only ask from i on.
            total = _number(args[0], int, 1, MAX_SAMPLE)
            places = [_number(a, int, 0, total - 1) for a in args[1:]]
            self._trial.rewind()
            self._replay_from, self._pick = 0, (total, places)
            return f"#OK SIM PICK {total} {len(places)}\n".encode()
        if sub == "PRESS" and len(args) in (3, 4):
            x = _number(args[0], int, 1, self.skin.rows)  # a node of this skin only
            y = _number(args[1], int, 1, self.skin.columns)
            newtons = _number(args[2], float, 0.0, MAX_NEWTONS)
            ramp_ms = _number(args[3], float, 0.0, MAX_RAMP_MS) if len(args) == 4 else 0.0
            self._indenters.append(self._trial.place(x, y, newtons, ramp_s=ramp_ms / 1000))
            return f"#OK SIM PRESS {' '.join([str(x), str(y), *args[2:]])}\n".encode()
        raise ValueError(f"unknown SIM command {sub!r} with {len(args)} argument(s)")


def _number(text: str, kind: type, low: float, high: float):
    try:
        value = kind(text)
    except ValueError:
        raise ValueError(f"{text!r} is not a number") from None
    if not low <= value <= high:  # NaN fails this too
        raise ValueError(f"{text} is outside {low}..{high}")
    return value
