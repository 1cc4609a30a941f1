"""A magnetic skin's recording, written the way public tactile datasets lay theirs out.

One CSV per press position of a 3 × 3 grid 8 mm apart (``press_x8_y16.csv``), each with
a ``timestamp`` (Unix seconds, 100 Hz), 15 magnetometer channels (``m1x..m5z``: five
magnetometers × xyz) and a 6-axis force/torque sensor (``Fx, Fy, Fz, Tx, Ty, Tz``) whose
``Fz`` reads compression as negative and carries an untared offset of 0.2–0.7 N (either
sign) per file. Presses of continuous force (1–5 N, drifting while held) alternate with
rest; the magnetometers drop frames (every channel 0) and repeat stale ones (equal to
the row before). Two-touch files (``press_x0_y0_x16_y16.csv``) have two indenters and
the total force only.

This module knows nothing of eskin (it imports none of it): it is another lab's
instrument, and :class:`Written` says what was written, for tests to check what eskin
makes of it.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

GRID_MM = (0.0, 8.0, 16.0)
CHANNELS = [f"m{i}{axis}" for i in range(1, 6) for axis in "xyz"]
FT_COLUMNS = ["Fx", "Fy", "Fz", "Tx", "Ty", "Tz"]
# The magnetometers under the skin (mm): the corners and the centre of the grid.
MAGNETOMETERS = np.array([[0.0, 0.0], [16.0, 0.0], [8.0, 8.0], [0.0, 16.0], [16.0, 16.0]])
RATE_HZ = 100
REST_S, RAMP_S, HOLD_S = 0.6, 0.2, 0.4
PRESSES_PER_FILE = 3
DEPTH_MM = 4.0        # the magnet layer above the magnetometers
GAIN = 400.0          # µT per N at the magnetometer's own position, roughly
NOISE_UT = 0.3
FORCE_NOISE_N = 0.02


@dataclass
class Written:
    """What the recording holds, as the instrument's own truth."""

    folder: Path
    files: list[Path] = field(default_factory=list)
    rows: int = 0
    dropped_frames: int = 0
    stale_repeats: int = 0
    offsets_n: dict[str, float] = field(default_factory=dict)  # per file, as Fz reads it
    true_force_n: list[np.ndarray] = field(default_factory=list)  # per file, per row
    cycle_s: float = REST_S + 2 * RAMP_S + HOLD_S  # one rest and one press

    def contact_share(self, contact_n: float) -> float:
        """The share of rows kept (neither dropped nor stale) whose true force exceeds
        ``contact_n``: what a contact rule at that threshold should find, up to noise."""
        forces = np.concatenate(self.true_force_n)
        return float((forces > contact_n).mean())


def field_ut(presses: list[tuple[float, float, float]], baseline: np.ndarray) -> np.ndarray:
    """The 15 readings under ``presses`` ((force N, x mm, y mm) each): a dipole-like
    response per magnetometer, smooth in the force and falling with the distance."""
    out = baseline.copy()
    for force, px, py in presses:
        if force <= 0:
            continue
        d = np.array([px, py]) - MAGNETOMETERS             # 5 × 2, mm
        r3 = (np.sum(d ** 2, axis=1) + DEPTH_MM ** 2) ** 1.5
        scale = GAIN * force * DEPTH_MM ** 3 / r3 / (1 + 0.08 * force)  # saturates a little
        out[0::3] += scale * d[:, 0] / DEPTH_MM
        out[1::3] += scale * d[:, 1] / DEPTH_MM
        out[2::3] -= scale
    return out


def _profile(rng: np.random.Generator) -> np.ndarray:
    """True force (N) per row of one file: rest, then presses of 1–5 N, each ramped up,
    held (drifting) and released, and rest at the end."""
    n = int(RATE_HZ * REST_S)
    ramp, hold = int(RATE_HZ * RAMP_S), int(RATE_HZ * HOLD_S)
    parts = [np.zeros(n)]
    for _ in range(PRESSES_PER_FILE):
        peak = rng.uniform(1.0, 5.0)
        held = peak * (1 + np.cumsum(rng.normal(0, 0.004, hold)))
        parts += [np.linspace(0, peak, ramp, endpoint=False), held,
                  np.linspace(held[-1], 0, ramp, endpoint=False), np.zeros(n)]
    return np.concatenate(parts)


def _write(path: Path, rows: list[list[float]]) -> None:
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["timestamp", *CHANNELS, *FT_COLUMNS])
        writer.writerows(rows)


def _file(rng: np.random.Generator, path: Path, contacts: list[tuple[float, float]],
          baseline: np.ndarray, start_s: float, written: Written, *,
          dropped: float, stale: float) -> None:
    force = _profile(rng)
    offset = rng.choice([-1.0, 1.0]) * rng.uniform(0.2, 0.7)
    share = rng.uniform(0.3, 0.7)  # how two indenters split the total
    rows, kept = [], []
    n = len(force)
    # Hiccups: never at the first row, never one right after another.
    slots = rng.permutation(np.arange(2, n - 1, 3))
    n_dropped, n_stale = int(round(dropped * n)), int(round(stale * n))
    drop_at, stale_at = set(slots[:n_dropped]), set(slots[n_dropped:n_dropped + n_stale])
    previous = None
    for i in range(n):
        splits = [share, 1 - share] if len(contacts) > 1 else [1.0]
        presses = [(force[i] * s, x, y) for s, (x, y) in zip(splits, contacts, strict=True)]
        reading = field_ut(presses, baseline) + rng.normal(0, NOISE_UT, 15)
        if i in drop_at:
            reading = np.zeros(15)
        elif i in stale_at:
            reading = previous.copy()
        else:
            kept.append(force[i])
        ft = [rng.normal(0, 0.05), rng.normal(0, 0.05),
              -force[i] + offset + rng.normal(0, FORCE_NOISE_N),
              *rng.normal(0, 0.002, 3)]
        rows.append([round(start_s + i / RATE_HZ, 3), *np.round(reading, 3),
                     *np.round(ft, 4)])
        previous = reading
    _write(path, rows)
    written.files.append(path)
    written.rows += n
    written.dropped_frames += n_dropped
    written.stale_repeats += n_stale
    written.offsets_n[path.name] = offset
    written.true_force_n.append(np.array(kept))


def write_recording(folder: Path, *, seed: int = 7, dropped: float = 0.01,
                    stale: float = 0.02) -> Written:
    """One CSV per press position of the 3 × 3 grid in ``folder``."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    baseline = rng.normal(0, 40, 15)
    written = Written(folder)
    start = 1_700_000_000.0
    for x in GRID_MM:
        for y in GRID_MM:
            _file(rng, folder / f"press_x{x:g}_y{y:g}.csv", [(x, y)], baseline, start,
                  written, dropped=dropped, stale=stale)
            start += 100.0
    return written


def write_two_touch_recording(folder: Path, *, seed: int = 8, dropped: float = 0.01,
                              stale: float = 0.02) -> Written:
    """One CSV per pair of press positions (every pair of corners and the centre), two
    indenters pressed together, the F/T sensor under the skin giving their total."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    baseline = rng.normal(0, 40, 15)
    written = Written(folder)
    points = [(0.0, 0.0), (16.0, 0.0), (8.0, 8.0), (0.0, 16.0), (16.0, 16.0)]
    start = 1_700_000_000.0
    for i, a in enumerate(points):
        for b in points[i + 1:]:
            name = f"press_x{a[0]:g}_y{a[1]:g}_x{b[0]:g}_y{b[1]:g}.csv"
            _file(rng, folder / name, [a, b], baseline, start, written,
                  dropped=dropped, stale=stale)
            start += 100.0
    return written
