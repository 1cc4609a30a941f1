"""Link faults for the simulated board: what a real bench does to a serial line.

The transports in ``simulate.py`` pass the board's answers through
:class:`FaultyLine`, which damages them frame line by frame line from its own
seeded stream. Kinds, each a probability per frame line (``sim_board.faults``):

``drop``     1–8 bytes of the line are lost (a lost newline merges two lines)
``garbage``  1–40 random bytes arrive before the line (half the time ending in
             a newline, otherwise glued to the frame)
``reset``    the board restarts before the line: the rest of the answer is lost,
             ``#HELLO`` comes again, the sequence counter starts from 0 and the
             stretch and indenters are forgotten (a power cycle)
``stall``    the board falls silent for up to ``stall_s`` before the line
``vanish``   the port disappears before the line (pty closed, socket dropped)
             and comes back ``vanish_s`` later, at the same path

Two more are drawn per ``#OK`` line, from a stream of their own (so the kinds above
draw as before): ``ok_dup``, the ``#OK`` sent again at the start of the board's next
answer (it arrives after the host's next request); ``ok_spoof``, a ``SAMPLE``'s
``#OK`` sent early too, before a frame of its answer drawn at random.

Byte corruption (a flipped byte or a truncated line) is the board's own
``corrupt_fraction``: it lives in ``board.py``. It stayed there while that
file's bytes were part of the simulator's identity; now the identity is what
the board answers to a fixed probe (with ``corrupt_fraction`` 0), so moving
it would keep every dataset. This layer still counts it — a frame line that
leaves the board already failing its CRC is logged as ``corrupt`` — so the
fault log has every kind. With ``log`` set, every fault
is appended to that file as it happens (``<kind>\\t<detail>``), flushed, so
a test or the soak counts them even after the process was killed; so is every
``SAMPLE`` request (``request\\tSAMPLE <n>``), which the soak counts.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from eskin.device.board import SimulatedBoard
from eskin.device.protocol import Frame, parse_line

KINDS = ("corrupt", "drop", "garbage", "reset", "stall", "vanish", "ok_dup", "ok_spoof")


@dataclass(frozen=True)
class LinkFaults:
    """Probabilities per frame line of each injected fault, and their durations."""

    drop: float = 0.0
    garbage: float = 0.0
    reset: float = 0.0
    stall: float = 0.0
    vanish: float = 0.0
    stall_s: float = 0.5
    vanish_s: float = 0.5
    seed: int = 0
    log: str | None = None
    ok_dup: float = 0.0     # per #OK line: sent again before the next answer
    ok_spoof: float = 0.0   # per SAMPLE #OK: sent early too, before one of its frames

    def __post_init__(self) -> None:
        rates = [self.drop, self.garbage, self.reset, self.stall, self.vanish]
        if any(not 0.0 <= r < 1.0 for r in rates) or sum(rates) >= 1.0:
            raise ValueError(f"sim_board.faults: each rate must be in [0, 1) and together < 1, "
                             f"got {dict(zip(KINDS[1:6], rates, strict=True))}")
        if not (0.0 <= self.ok_dup < 1.0 and 0.0 <= self.ok_spoof < 1.0):
            raise ValueError(f"sim_board.faults: ok_dup and ok_spoof must be in [0, 1), got "
                             f"{self.ok_dup} and {self.ok_spoof}")
        if self.stall_s < 0 or self.vanish_s < 0:
            raise ValueError("sim_board.faults: stall_s and vanish_s must be ≥ 0")

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any] | None) -> LinkFaults:
        values = dict(values or {})
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"sim_board.faults: unknown key(s) {unknown}; known: {sorted(known)}")
        return cls(**values)

    def as_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class Pause:
    """The transport stays silent this long; ``vanish``: with the port gone."""

    seconds: float
    vanish: bool = False


Chunk = bytes | Pause


class FaultyLine:
    """The board behind a faulty line: command lines in, chunks (bytes or pauses) out."""

    def __init__(self, make_board: Callable[[], SimulatedBoard], faults: LinkFaults) -> None:
        self.make_board = make_board
        self.board = make_board()
        self.faults = faults
        self._rng = np.random.default_rng([faults.seed, 3])
        self._log = (open(faults.log, "a", encoding="ascii", errors="backslashreplace")  # noqa: SIM115
                     if faults.log else None)
        cuts = np.cumsum([faults.drop, faults.garbage, faults.reset, faults.stall,
                          faults.vanish])
        self._cuts = cuts
        self._ok_rng = np.random.default_rng([faults.seed, 5])  # #OK faults: their own stream
        self._ok_due = b""  # ok_dup: the #OK to send before the next answer
        self.injected = dict.fromkeys(KINDS, 0)

    def close(self) -> None:
        if self._log:
            self._log.close()

    def _note(self, kind: str, detail: str) -> None:
        self.injected[kind] += 1
        if self._log:
            self._log.write(f"{kind}\t{detail}\n")
            self._log.flush()

    def asked(self, command: bytes) -> None:
        """Log a ``SAMPLE`` request (the soak counts requests and the frames they ask)."""
        if self._log and command.strip().upper().startswith(b"SAMPLE"):
            self._log.write(f"request\t{command.strip().decode('ascii', 'replace')}\n")
            self._log.flush()

    def _ok_faults(self, lines: list[bytes]) -> list[bytes]:
        """``lines`` with this answer's #OK faults: the last answer's duplicate first, a
        SAMPLE's #OK early too; the #OK that is to be duplicated is noted."""
        out = [self._ok_due] if self._ok_due else []
        self._ok_due = b""
        frames = [i for i, line in enumerate(lines) if line.startswith(b"D,")]
        last = lines[-1] if lines else b""
        if (self.faults.ok_spoof and frames and last.startswith(b"#OK SAMPLE")
                and self._ok_rng.random() < self.faults.ok_spoof):
            at = frames[int(self._ok_rng.integers(0, len(frames)))]
            self._note("ok_spoof", f"before line {at} of {len(lines)}")
            lines = [*lines[:at], last, *lines[at:]]
        for line in lines:
            if (self.faults.ok_dup and line.startswith(b"#OK")
                    and self._ok_rng.random() < self.faults.ok_dup):
                self._note("ok_dup", ascii(line.strip()))
                self._ok_due = line
        return out + lines

    def answer(self, output: bytes) -> list[Chunk]:
        """Damage the board's answer ``output`` line by line."""
        if not output:
            return []
        chunks: list[Chunk] = []
        lines = output.splitlines(keepends=True)
        if self.faults.ok_dup or self.faults.ok_spoof:
            lines = self._ok_faults(lines)
        for i, line in enumerate(lines):
            if not line.startswith(b"D,"):
                chunks.append(line)
                continue
            if not isinstance(parse_line(line.rstrip(b"\n"), self.board.skin.terminals),
                              Frame):
                self._note("corrupt", ascii(line[:24]))
            draw = self._rng.random()
            kind = int(np.searchsorted(self._cuts, draw, side="right"))
            if kind == 0:  # drop
                at = int(self._rng.integers(0, len(line)))
                span = int(self._rng.integers(1, 9))
                self._note("drop", f"{span} byte(s) at {at}")
                chunks.append(line[:at] + line[at + span:])
            elif kind == 1:  # garbage
                junk = self._rng.integers(0, 256, int(self._rng.integers(1, 41)))
                junk = np.where(junk == ord("\n"), 0, junk).astype(np.uint8).tobytes()
                if self._rng.random() < 0.5:
                    junk += b"\n"
                self._note("garbage", f"{len(junk)} byte(s)")
                chunks += [junk, line]
            elif kind == 2:  # reset: a fresh board, the rest of this answer never sent
                self._note("reset", f"before line {i} of {len(lines)}")
                wire_noise = self.board._corrupt_rng
                self.board = self.make_board()
                # The line's noise does not restart with the board: without this, every
                # power cycle would replay the same corruption pattern from its start.
                self.board._corrupt_rng = wire_noise
                chunks.append(self.board.hello())
                return chunks
            elif kind == 3:  # stall
                seconds = float(self._rng.uniform(0, self.faults.stall_s))
                self._note("stall", f"{seconds:.3f} s")
                chunks += [Pause(seconds), line]
            elif kind == 4:  # vanish
                # What the board sends while unplugged goes nowhere: the rest is lost.
                self._note("vanish", f"{self.faults.vanish_s:g} s")
                chunks.append(Pause(self.faults.vanish_s, vanish=True))
                return chunks
            else:
                chunks.append(line)
        return chunks
