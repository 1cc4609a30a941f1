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
  ``seating_variation``): light weights read imprecisely, seated heavy ones
  precisely (the paper's Fig. 6). The strain spreads over neighbouring nodes
  with a compact kernel that reaches ``reach_nodes`` nodes
  each way and no further. A node's capacitance grows as 1/(1 − ε); a
  terminal strip sums its nodes.
* **A hand-made skin.** The four 0.5 mm Ecoflex layers are cast, and the
  carbon-grease terminals brushed through a stencil, by hand: each node's
  dielectric thickness and overlap differ, so each node compresses by its own
  factor (lognormal, SD ``node_sensitivity_spread``, drawn once per skin).
* **Read-out.** Each terminal has its own baseline and CAV424 gain. Per trial,
  the indenter lands off-centre (placement variation) and seats differently
  (its F_seat; a dead weight always passes its whole weight to the rigid-backed
  skin, so the load itself does not vary); and the baseline
  wanders (slow drift: an offset per trial and a random walk within it).
  Every reading has white noise. The CAV424 maps relative capacitance to
  volts, clipped to its supply, and the Arduino's ADC quantises to 10 bits.
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
    drift_step_pf: float = 0.005
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
                     "cav424_gain_v", "supply_v"):
            if getattr(self, name) <= 0:
                raise ValueError(f"sim.{name} must be positive, got {getattr(self, name)}")
        for name in ("noise_pf", "drift_offset_pf", "drift_step_pf", "placement_sd_nodes",
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


@dataclass(frozen=True)
class Indenter:
    """A weight on node (x, y), x in 1..rows and y in 1..columns; ``offset`` is its placement
    error in node pitches, ``seating`` the factor its tilt puts on the load that seats it
    fully."""

    x: int
    y: int
    newtons: float
    offset: tuple[float, float] = (0.0, 0.0)
    seating: float = 1.0


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
        """Noise-free terminal capacitances in pF: x1..xR then y1..yC."""
        gap_gain = 1.0 / (1.0 - self.strain_field(indenters, stretch)) - 1.0
        indentation = np.concatenate([gap_gain.mean(axis=1), gap_gain.mean(axis=0)])
        stretched = self.baseline_pf * (1 + self.stretch_sensitivity * (stretch - 1))
        return stretched * (1 + indentation)

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
    """The readings of one trial: a noise and drift stream from its own seed.

    ``Trial(model, seed_words)`` is deterministic: the same words give the
    same placements and the same frames when the frames are requested alike (a
    request's n frames are drawn at once, so its noise depends on n).
    """

    def __init__(self, model: SkinModel, seed_words: Sequence[int]) -> None:
        self.model = model
        self.rng = np.random.default_rng([model.params.seed, 1, *seed_words])
        p = model.params
        self._drift = p.drift_offset_pf * self.rng.standard_normal(model.skin.terminals)
        self._first_sample: tuple[dict, np.ndarray] | None = None  # for rewind()

    def place(self, x: int, y: int, newtons: float) -> Indenter:
        """The indenter as it lands: off-centre, and more or less squarely seated."""
        offset = self.model.placement_offset(self.rng)
        seating = float(np.exp(self.model.params.seating_variation * self.rng.standard_normal()))
        self._first_sample = None
        return Indenter(x, y, newtons, offset, seating)

    def rewind(self) -> None:
        """Back to the first frame sampled since the last placement, the placements kept:
        what is sampled next reads as it did then."""
        if self._first_sample is not None:
            state, drift = self._first_sample
            self.rng.bit_generator.state = state
            self._drift = drift.copy()

    def sample_pf(self, n: int, stretch: float, indenters: Sequence[Indenter]) -> np.ndarray:
        """n noisy capacitance readings in pF, shape (n, terminals)."""
        if self._first_sample is None:
            self._first_sample = (self.rng.bit_generator.state, self._drift.copy())
        p = self.model.params
        terminals = self.model.skin.terminals
        clean = self.model.capacitance(stretch, indenters)
        walk = self._drift + np.cumsum(
            p.drift_step_pf * self.rng.standard_normal((n, terminals)), axis=0)
        self._drift = walk[-1] if n else self._drift
        noise = p.noise_pf * self.rng.standard_normal((n, terminals))
        return clean + walk + noise

    def sample_counts(self, n: int, stretch: float, indenters: Sequence[Indenter]) -> np.ndarray:
        return self.model.to_counts(self.sample_pf(n, stretch, indenters))
