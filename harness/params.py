"""bench/params.yaml and stress/params.yaml: `make bench`'s and `make stress`'s knobs,
beside the harness that reads them (eskin reads only ``learning_curve``:
eskin.config.planning)."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

from eskin.config.acquisition import Faults
from eskin.config.base import (
    BENCH_PARAMS,
    STRESS_PARAMS,
    Backend,
    Count,
    Jobs,
    NonNegative,
    Positive,
    Probability,
    Scheme,
    Section,
    Seed,
    real,
)
from eskin.config.planning import LearningCurve


class Soak(Section):
    corrupt_fraction: Probability
    faults: Faults
    timeout_s: Positive
    reconnect_s: NonNegative
    kill_at: list[real(gt=0, lt=1)]


class Fuzz(Section):
    examples: Count


class Variant(BaseModel):
    model_config = ConfigDict(extra="allow", strict=True)
    model: str


class Bench(Section):
    schemes: Annotated[list[Scheme], Field(min_length=1)]
    evaluate_folds: Count
    scaling_fractions: list[Positive]
    seed: Seed
    n_jobs: Jobs
    backend: Backend
    import_rows: list[Count] = []
    localise_sizes: list[Annotated[int, Field(ge=2, le=32)]] = []  # localise_cost's N × N skins
    repro_baseline: str = ""  # the revision make bench's repro_speed times against
    tasks: dict[str, dict[str, Variant]]


class NoiseScene(Section):
    stretches: Annotated[list[real(ge=1)], Field(min_length=1)]
    forces: Annotated[list[NonNegative], Field(min_length=1)]
    samples: Count


class Stress(Section):
    trials: Count
    folds: Annotated[int, Field(ge=2)]
    seed: Seed
    noise_scene: NoiseScene
    large_gp_rows: Annotated[int, Field(ge=0)]


class LiveHour(Section):
    """make bench's live hour (harness/live_hour.py): the script of the hour."""

    seed: Seed
    minutes: Positive
    untouched_s: Positive        # between two events of the script
    presses: Annotated[int, Field(ge=0)]
    press_s: Positive
    sustained_s: Positive
    stretches_mm: list[NonNegative]
    retare_after_sustained: bool
    press_ramp_ms: NonNegative
    batch_frames: Count
    # the simulated board's drift SD for the hour (pF), in place of params.yaml's
    # sim.drift_offset_pf (none: that); its own, so that a harder hour does not redraw data
    drift_offset_pf: NonNegative | None = None


class HardHourTargets(Section):
    """The harder hour's targets, for every part (issue 57, item 6)."""

    phantom_share: real(ge=0, le=1)       # of its untouched frames after 100 ms
    phantom_after_release_s: NonNegative  # the longest run of contact on untouched frames
    missed_share: real(ge=0, le=1)        # of its pressed frames after 100 ms
    cv_sds: NonNegative                   # location, force: fold SDs worse than CV, at most
    held_share: real(ge=0, le=1)          # the long presses' frames in contact


class HardHour(Section):
    """make bench's harder hour (harness/hard_hour.py): its script, board and targets."""

    seed: Seed
    drift_offset_pf: NonNegative          # the board's drift SD in every part (pF)
    press_ramp_ms: NonNegative
    batch_frames: Count
    untouched_s: Positive                 # between two presses
    light_press_s: Positive
    held_presses: Annotated[int, Field(ge=0)]
    held_press_s: Positive
    taps: Annotated[int, Field(ge=0)]
    tap_ms: Positive
    long_presses_min: list[Positive]
    after_long_s: NonNegative
    untouched_min: Positive
    targets: HardHourTargets


class BenchParams(Section):
    """bench/params.yaml: `make bench`'s knobs (bench/dvc.yaml)."""

    file = BENCH_PARAMS

    bench: Bench
    soak: Soak
    fuzz: Fuzz
    live_hour: LiveHour
    hard_hour: HardHour
    learning_curve: LearningCurve


class StressParams(Section):
    """stress/params.yaml: `make stress`'s knobs (stress/dvc.yaml)."""

    file = STRESS_PARAMS

    stress: Stress
