"""A physics model of a row/column capacitive e-skin and its read-out chain.

Every number comes from :class:`SkinParams` (``sim:`` in params.yaml); the skin's rows
and columns from the :class:`~eskin.skin.Skin` it is built for (the scene's; the paper's
10 × 10 by default).

* **Stretch.** An incompressible dielectric stretched by λ along the skin
  grows its electrode area by √λ and thins by 1/√λ, so C ∝ λ: capacitance
  is linear in stretch, with a per-terminal sensitivity near 1.
* **Indentation.** A weight of F newtons compresses the dielectric under its
  footprint by a strain that rises linearly and saturates as the Ecoflex 00-50
  compacts (ε_max·r/(1 + r), r = (F/F½)^h, h = ``force_hill``); a stretched
  skin is stiffer, so F½ grows as λ^k (stretch–indentation coupling). A
  hand-placed rigid weight does not bear on its whole footprint at once: it
  rests on the skin's texture and on the low side of its tilt, and its
  contact area grows with the load (Hertz: a ∝ F^⅔) until the load that
  seats it fully, F_seat (``seating_force_n``). The share of the footprint
  pressing is min(1, (F/F_seat)^⅔), so light loads give less signal, and
  F_seat varies from trial to trial with the tilt (lognormal, SD
  ``seating_variation``): a light weight's error is a large share of its force,
  a seated heavy one's a smaller share (the paper's Fig. 6). The strain spreads over
  neighbouring nodes with a compact kernel that reaches ``reach_nodes`` nodes each way and
  no further. A node's capacitance grows as 1/(1 − ε); a
  terminal strip sums its nodes.
* **A hand-made skin.** The four 0.5 mm Ecoflex layers are cast, and the
  carbon-grease terminals brushed through a stencil, by hand: each node's
  dielectric thickness and overlap differ, so each node compresses by its own
  factor (lognormal, SD ``node_sensitivity_spread``, drawn once per skin).
* **Creep.** Ecoflex is viscoelastic: under a sustained load the dielectric goes on
  compressing, and after release it recovers, both with a retardation time (a
  standard linear solid: a delayed strain ``creep_fraction`` of the instantaneous
  one, reached and lost with time constant ``creep_time_s``). A press held for
  minutes reads a few percent stronger at its end; a release leaves a residue that
  relaxes away.
* **A hand press ramps.** ``SIM PRESS … <ramp_ms>`` brings its load from 0 to the
  full weight over that time, as a finger or a hand-lowered weight does; the
  acquisition's dead weights are placed at once.
* **Read-out.** Each terminal has its own baseline and CAV424 gain. Per trial,
  the indenter lands off-centre (placement variation) and seats differently
  (its F_seat; a dead weight always passes its whole weight to the rigid-backed
  skin, so the load itself does not vary). Every reading has white noise. The
  CAV424 maps relative capacitance to volts, clipped to its supply, and the
  Arduino's ADC quantises to 10 bits.
* **Drift in time.** Each terminal's baseline wanders with the lab's temperature
  and humidity: a stationary, mean-reverting (Ornstein–Uhlenbeck) process in board
  time, SD ``drift_offset_pf`` and time constant ``drift_time_constant_s``, so it is
  bounded and its random-walk part, σ·√(2/τ) per √s, is as small as a real skin's.
  It is a function of board time, evaluated by random Fourier features (a sum of
  cosines whose frequencies are drawn from the OU's Lorentzian spectrum): any
  frame of any trial reads it without replaying the ones before, so a trial, a
  resumed acquisition and an hour of streaming read the same skin. An acquisition's
  trials are keyed by their condition, not taken in an order, so each begins at a
  board time of its own, drawn from its seed over a span of thousands of time
  constants: its offset is a draw from the drift's stationary law (SD σ), as
  trials taken on different days are.

Time is board time: a reading every frame period (the board's), the stepper's moves
and the trial's start. Two things are left out on purpose: a trial begins relaxed
(no creep residue from the one before), and the dead weights are read from the
moment they land, so creep moves an acquisition's 20-frame trial by about 0.1 % of
its strain; it matters for live presses of seconds and minutes.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from eskin.skin import PAPER_SKIN, AnySkin, Skin


@dataclass(frozen=True)
class SkinParams:
    """Parameters of the simulated skin and read-out (``sim:`` in params.yaml)."""

    seed: int = 20230529
    baseline_pf: float = 20.0
    baseline_spread: float = 0.05
    stretch_sensitivity_spread: float = 0.03
    strain_max: float = 0.6
    force_half_n: float = 3.0
    force_hill: float = 1.5
    stretch_stiffening: float = 1.5
    reach_nodes: int = 2
    placement_sd_nodes: float = 0.15
    placement_max_nodes: float = 0.45
    node_sensitivity_spread: float = 0.0
    seating_force_n: float = 0.0
    seating_variation: float = 0.0
    noise_pf: float = 0.03
    drift_offset_pf: float = 0.1
    drift_time_constant_s: float = 300.0
    creep_fraction: float = 0.05
    creep_time_s: float = 10.0
    cav424_ref_pf: float = 16.0
    cav424_gain_v: float = 4.0
    cav424_gain_spread: float = 0.05
    cav424_offset_v: float = 0.5
    supply_v: float = 5.0
    adc_bits: int = 10

    @classmethod
    def from_mapping(cls, values: Mapping[str, object]) -> SkinParams:
        """Build from a params.yaml section; unknown keys are an error, not a silent no-op."""
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"unknown simulator parameter(s) {unknown}; known: {sorted(known)}")
        params = cls(**values)  # type: ignore[arg-type]
        params.validate()
        return params

    def validate(self) -> None:
        if not 0 < self.strain_max < 1:
            raise ValueError(f"sim.strain_max must be in (0, 1), got {self.strain_max}")
        if self.placement_max_nodes >= 0.5:
            raise ValueError("sim.placement_max_nodes must be below 0.5 so that an indenter "
                             "stays on its node")
        for name in ("baseline_pf", "force_half_n", "force_hill", "cav424_ref_pf",
                     "cav424_gain_v", "supply_v", "drift_time_constant_s", "creep_time_s"):
            if getattr(self, name) <= 0:
                raise ValueError(f"sim.{name} must be positive, got {getattr(self, name)}")
        for name in ("noise_pf", "drift_offset_pf", "creep_fraction",
                     "placement_sd_nodes",
                     "seating_variation", "seating_force_n", "node_sensitivity_spread",
                     "baseline_spread", "stretch_sensitivity_spread", "cav424_gain_spread"):
            if getattr(self, name) < 0:
                raise ValueError(f"sim.{name} must not be negative, got {getattr(self, name)}")
        if self.reach_nodes < 0 or not 1 <= self.adc_bits <= 16:
            raise ValueError("sim.reach_nodes must be ≥ 0 and sim.adc_bits in 1..16")

    def as_dict(self) -> dict[str, object]:
        return dataclasses.asdict(self)


def skin_params(sim: Any) -> SkinParams:
    """The simulated skin of a params file's ``sim:`` section (``params.sim``, a
    :class:`eskin.config.Sim`)."""
    return SkinParams.from_mapping(sim.model_dump())


DRIFT_COMPONENTS = 64  # cosines per terminal: the drift's marginal is then near Gaussian
DRIFT_SPAN_S = 1e6  # trials begin somewhere in 11.6 days of board time: 3,000 drift time constants


@dataclass(frozen=True)
class Indenter:
    """A weight on node (x, y), x in 1..rows and y in 1..columns; ``offset`` is its placement
    error in node pitches, ``seating`` the factor its tilt puts on the load that seats it
    fully. Placed at board time ``placed_s``, its load ramps from 0 to ``newtons`` over
    ``ramp_s`` (0: at once)."""

    x: int
    y: int
    newtons: float
    offset: tuple[float, float] = (0.0, 0.0)
    seating: float = 1.0
    placed_s: float = 0.0
    ramp_s: float = 0.0

    def load(self, t_s: float) -> float:
        """The load it puts on the skin at board time ``t_s``."""
        if self.ramp_s <= 0:
            return self.newtons
        return self.newtons * min(1.0, max(0.0, (t_s - self.placed_s) / self.ramp_s))

    def ramping(self, t_s: float) -> bool:
        return self.ramp_s > 0 and t_s < self.placed_s + self.ramp_s


def spread_kernel(distance: np.ndarray, reach_nodes: int) -> np.ndarray:
    """Share of the peak strain felt ``distance`` node pitches away.

    (1 − (d/R)²)² with R = reach + ½: smooth, 1 at the centre, and exactly 0
    from reach + ½ on, so that with placement errors below ½ pitch an
    indenter reaches ``reach_nodes`` nodes each way and never one more.
    """
    radius = reach_nodes + 0.5
    return np.clip(1.0 - (np.asarray(distance, dtype=float) / radius) ** 2, 0.0, None) ** 2


class SkinModel:
    """The skin: terminal capacitances from stretch and indenters, then ADC counts.

    Per-terminal properties (baselines, sensitivities, gains) are drawn once
    from ``params.seed``: they are this particular skin. ``skin`` is its rows and
    columns (the paper's 10 × 10 draws exactly what it always drew).
    """

    def __init__(self, params: SkinParams, skin: AnySkin = PAPER_SKIN) -> None:
        params.validate()
        if not isinstance(skin, Skin):
            raise ValueError(f"the simulated skin is a row/column skin; {skin.describe()} is "
                             "recorded by another instrument (source: import)")
        self.params = params
        self.skin = skin
        self.x_nodes = np.arange(1, skin.rows + 1, dtype=float)  # node positions, in pitches
        self.y_nodes = np.arange(1, skin.columns + 1, dtype=float)
        rng = np.random.default_rng([params.seed, 0])
        n = skin.terminals
        spread = params.baseline_spread * rng.standard_normal(n)
        self.baseline_pf = params.baseline_pf * (1 + spread)
        self.stretch_sensitivity = 1 + params.stretch_sensitivity_spread * rng.standard_normal(n)
        self.cav424_gain_v = params.cav424_gain_v * (
            1 + params.cav424_gain_spread * rng.standard_normal(n))
        # Drawn after the others, so that adding it left this skin's other draws alone.
        self.node_sensitivity = np.exp(
            params.node_sensitivity_spread * rng.standard_normal((skin.rows, skin.columns)))
        # The drift's cosines, from their own stream: frequencies from the OU process's
        # Lorentzian spectrum (a Cauchy law of scale 1/τ), phases uniform, so that the sum's
        # covariance is σ² exp(−|Δt|/τ) (random Fourier features, Rahimi & Recht 2007).
        drift_rng = np.random.default_rng([params.seed, 3])
        shape = (n, DRIFT_COMPONENTS)
        self._drift_frequency = drift_rng.standard_cauchy(shape) / params.drift_time_constant_s
        self._drift_phase = drift_rng.uniform(0.0, 2 * np.pi, shape)
        self._drift_amplitude = params.drift_offset_pf * np.sqrt(2.0 / DRIFT_COMPONENTS)

    # ----------------------------------------------------------- physics

    def peak_strain(self, newtons: float, stretch: float, seating: float = 1.0) -> float:
        """Mean compression over the indenter's footprint: monotone in force, saturating.

        ``seating`` scales this trial's full-seating load (``seating_force_n``)."""
        p = self.params
        if newtons <= 0:
            return 0.0
        half = p.force_half_n * stretch ** p.stretch_stiffening
        ratio = (newtons / half) ** p.force_hill
        seat_n = p.seating_force_n * seating
        pressing = min(1.0, (newtons / seat_n) ** (2 / 3)) if seat_n > 0 else 1.0
        return p.strain_max * pressing * ratio / (1 + ratio)

    def strain_field(self, indenters: Sequence[Indenter], stretch: float) -> np.ndarray:
        """Strain at each node, shape (rows, columns) indexed [x-1, y-1]."""
        p = self.params
        field = np.zeros((self.skin.rows, self.skin.columns))
        for ind in indenters:
            peak = self.peak_strain(ind.newtons, stretch, ind.seating)
            if peak == 0.0:
                continue
            wx = spread_kernel(self.x_nodes - (ind.x + ind.offset[0]), p.reach_nodes)
            wy = spread_kernel(self.y_nodes - (ind.y + ind.offset[1]), p.reach_nodes)
            field += peak * np.outer(wx, wy)
        # Two indenters cannot squeeze the dielectric past what one can.
        return np.minimum(field * self.node_sensitivity, p.strain_max)

    def capacitance(self, stretch: float, indenters: Sequence[Indenter] = ()) -> np.ndarray:
        """Noise-free terminal capacitances in pF: x1..xR then y1..yC (the indenters at
        their full load, no creep)."""
        return self.capacitance_of_strain(self.strain_field(indenters, stretch), stretch)

    def capacitance_of_strain(self, strain: np.ndarray, stretch: float) -> np.ndarray:
        """Terminal capacitances in pF of a strain field (..., rows, columns)."""
        gap_gain = 1.0 / (1.0 - strain) - 1.0
        indentation = np.concatenate([gap_gain.mean(axis=-1), gap_gain.mean(axis=-2)], axis=-1)
        stretched = self.baseline_pf * (1 + self.stretch_sensitivity * (stretch - 1))
        return stretched * (1 + indentation)

    def drift_pf(self, times_s: np.ndarray, block: int = 2048) -> np.ndarray:
        """Each terminal's baseline drift at these board times, in pF: (times, terminals)."""
        times = np.asarray(times_s, dtype=float)
        out = np.zeros((len(times), self.skin.terminals))
        if self._drift_amplitude == 0:
            return out
        for start in range(0, len(times), block):  # a bounded buffer for long answers
            phase = (times[start:start + block, None, None] * self._drift_frequency
                     + self._drift_phase)
            out[start:start + block] = self._drift_amplitude * np.cos(phase).sum(axis=2)
        return out

    def to_counts(self, capacitance_pf: np.ndarray) -> np.ndarray:
        """CAV424 voltage, clipped to the supply, then ADC counts (int)."""
        p = self.params
        volts = p.cav424_offset_v + self.cav424_gain_v * (
            capacitance_pf - p.cav424_ref_pf) / p.cav424_ref_pf
        full_scale = 2**p.adc_bits - 1
        counts = np.rint(np.clip(volts, 0.0, p.supply_v) / p.supply_v * full_scale)
        return counts.astype(np.int64)

    # ----------------------------------------------------------- randomness

    def placement_offset(self, rng: np.random.Generator) -> tuple[float, float]:
        p = self.params
        offset = np.clip(p.placement_sd_nodes * rng.standard_normal(2),
                         -p.placement_max_nodes, p.placement_max_nodes)
        return float(offset[0]), float(offset[1])


class Trial:
    """The readings of one trial: noise and placements from its own seed, drift and creep
    in board time.

    ``Trial(model, seed_words)`` is deterministic: the same words give the
    same placements and the same frames when the frames are requested alike (a
    request's n frames are drawn at once, so its noise depends on n). It begins with the
    skin relaxed at board time ``start_s`` (by default one drawn from the seed words,
    anywhere in :data:`DRIFT_SPAN_S`), and reads a frame every ``frame_period_s``.
    """

    def __init__(self, model: SkinModel, seed_words: Sequence[int], *,
                 start_s: float | None = None, frame_period_s: float = 0.012) -> None:
        if frame_period_s <= 0:
            raise ValueError(f"a trial's frame period must be positive, got {frame_period_s}")
        self.model = model
        self.rng = np.random.default_rng([model.params.seed, 1, *seed_words])
        if start_s is None:  # its own stream: the noise and placements stay as they were
            start_s = np.random.default_rng([model.params.seed, 4, *seed_words]).uniform(
                0.0, DRIFT_SPAN_S)
        self.t_s = float(start_s)
        self.frame_period_s = float(frame_period_s)
        self._creep = np.zeros((model.skin.rows, model.skin.columns))  # delayed strain
        self._first_sample: tuple[dict, float, np.ndarray] | None = None  # for rewind()

    def place(self, x: int, y: int, newtons: float, ramp_s: float = 0.0) -> Indenter:
        """The indenter as it lands, now: off-centre, and more or less squarely seated;
        its load ramps up over ``ramp_s``."""
        offset = self.model.placement_offset(self.rng)
        seating = float(np.exp(self.model.params.seating_variation * self.rng.standard_normal()))
        self._first_sample = None
        return Indenter(x, y, newtons, offset, seating, placed_s=self.t_s, ramp_s=ramp_s)

    def rewind(self) -> None:
        """Back to the first frame sampled since the last placement, the placements kept:
        what is sampled next reads as it did then."""
        if self._first_sample is not None:
            state, t_s, creep = self._first_sample
            self.rng.bit_generator.state = state
            self.t_s, self._creep = t_s, creep.copy()

    def wait(self, seconds: float, stretch: float, indenters: Sequence[Indenter]) -> None:
        """Let ``seconds`` of board time pass unread (a stepper's move): creep goes on."""
        if seconds > 0:
            self._strain(np.array([self.t_s + seconds]), stretch, indenters)
            self.t_s += seconds

    def _strain(self, times: np.ndarray, stretch: float,
                indenters: Sequence[Indenter]) -> np.ndarray:
        """The strain field at each of ``times`` (evenly spaced, from the last time read),
        (times, rows, columns); the creep state is left at the last of them."""
        model, p = self.model, self.model.params
        n = len(times)
        if not indenters and not self._creep.any():
            return np.zeros((n, model.skin.rows, model.skin.columns))
        if any(ind.ramping(t) for ind in indenters for t in (self.t_s, times[-1])):
            instant = np.stack([model.strain_field(
                [dataclasses.replace(ind, newtons=ind.load(t), ramp_s=0.0) for ind in indenters],
                stretch) for t in times])
        else:
            instant = np.broadcast_to(model.strain_field(indenters, stretch),
                                      (n, model.skin.rows, model.skin.columns))
        if p.creep_fraction == 0:
            return instant
        # The delayed strain relaxes toward creep_fraction × the instantaneous one, exactly
        # for a load held over each step (a standard linear solid's Kelvin element).
        target = p.creep_fraction * instant
        steps = np.diff(np.concatenate([[self.t_s], times]))
        decay = np.exp(-steps / p.creep_time_s)
        creep = np.empty_like(instant)
        state = self._creep
        for k in range(n):
            state = target[k] + (state - target[k]) * decay[k]
            creep[k] = state
        self._creep = state.copy()
        return np.minimum(instant + creep, p.strain_max)

    def sample_pf(self, n: int, stretch: float, indenters: Sequence[Indenter]) -> np.ndarray:
        """n noisy capacitance readings in pF, shape (n, terminals), one a frame period
        apart from the trial's board time on."""
        if self._first_sample is None:
            self._first_sample = (self.rng.bit_generator.state, self.t_s, self._creep.copy())
        p = self.model.params
        terminals = self.model.skin.terminals
        times = self.t_s + self.frame_period_s * np.arange(n)
        if n:
            clean = self.model.capacitance_of_strain(
                self._strain(times, stretch, indenters), stretch)
        else:
            clean = np.zeros((0, terminals))
        self.t_s += self.frame_period_s * n
        noise = p.noise_pf * self.rng.standard_normal((n, terminals))
        return clean + self.model.drift_pf(times) + noise

    def sample_counts(self, n: int, stretch: float, indenters: Sequence[Indenter]) -> np.ndarray:
        return self.model.to_counts(self.sample_pf(n, stretch, indenters))
