"""params.yaml's ``sim``, ``sim_board`` and ``acquire``: the simulated skin, its board, and
how every scene is acquired."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from eskin.config.base import Count, NonNegative, Positive, Probability, Real, Section, Seed, real


class Sim(Section):
    """The simulated skin (eskin.device.physics.SkinParams reads it; a test checks that
    both name the same keys). Every key required: no built-in default stands in for a
    missing line. Declared here, not imported from the physics, so that a physics edit
    reruns acquisition and what follows from its data, not every stage that reads params."""

    seed: Seed
    baseline_pf: Positive
    baseline_spread: NonNegative
    stretch_sensitivity_spread: NonNegative
    strain_max: real(gt=0, lt=1)
    force_half_n: Positive
    force_hill: Positive
    stretch_stiffening: Real
    reach_nodes: Annotated[int, Field(ge=0)]
    placement_sd_nodes: NonNegative
    # below half a pitch, so that an indenter stays on its node
    placement_max_nodes: real(lt=0.5)
    node_sensitivity_spread: NonNegative
    seating_force_n: NonNegative
    seating_variation: NonNegative
    noise_pf: NonNegative
    drift_offset_pf: NonNegative
    drift_time_constant_s: Positive
    creep_fraction: NonNegative
    creep_time_s: Positive
    cav424_ref_pf: Positive
    cav424_gain_v: Positive
    cav424_gain_spread: NonNegative
    cav424_offset_v: Real
    supply_v: Positive
    adc_bits: Annotated[int, Field(ge=1, le=16)]


class Faults(Section):
    drop: Probability
    garbage: Probability
    reset: Probability
    stall: Probability
    vanish: Probability
    stall_s: NonNegative
    vanish_s: NonNegative
    seed: Seed
    log: str | None = None
    ok_dup: Probability = 0.0    # per #OK line: sent again before the next answer
    ok_spoof: Probability = 0.0  # per SAMPLE #OK: sent early too, before one of its frames


class SimBoard(Section):
    corrupt_fraction: Probability
    frame_period_ms: Count
    faults: Faults


class Acquire(Section):
    """How every scene is acquired; where each scene's data comes from is its own."""

    indenters: Literal["person", "board"] = "person"
    rest_length_mm: Positive
    timeout_s: Positive
    reconnect_s: NonNegative
    max_jump_counts: Positive
    max_attempts: Count
    max_interruptions: Count
