"""bench/params.yaml's ``learning_curve``: make bench's learning curves and `eskin plan`'s
costs (the one bench section eskin itself reads)."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, field_validator

from eskin.config.base import SCENE_NAME, Count, NonNegative, Positive, Section, TaskName


class PlanTarget(Section):
    """A target whose plan make bench records and scores (harness/plan_check.py)."""

    scene: Annotated[str, Field(pattern=SCENE_NAME)]
    target: str                 # <task>_<metric>, as `eskin plan --target` takes it
    value: float


class LearningCurve(Section):
    """make bench's learning curves (harness/learning_curve.py) and `eskin plan`'s costs."""

    repeats: Annotated[list[Count], Field(min_length=1)]  # trials per condition trained on
    placement_s: NonNegative    # an operator's time to place one trial's weights
    frames_per_s: Positive      # the board's frame rate (the firmware's, measured)
    gap_share: Annotated[float, Field(gt=0, lt=1)] = 0.8  # of the paper→bound gap, to close
    gap_tasks: list[TaskName] = []   # the tasks whose recommended repeats are checked
    # Held-out draws per point: repetition h of every condition held out, the model trained
    # on the r after it (cyclically); the planner reads the spread over them.
    draws: Count = 5
    # The share of new recordings a plan promises reach its target (the draws' lower end).
    reliability: Annotated[float, Field(gt=0.5, lt=1)] = 0.9
    # make bench's plan check: the planner's answer for each target recorded on fresh
    # repetitions of the simulated skin, scored on `check_recordings` more never trained on.
    checks: list[PlanTarget] = []
    check_recordings: Annotated[int, Field(ge=2)] = 10

    @field_validator("repeats")
    @classmethod
    def _increasing(cls, value: list[int]) -> list[int]:
        if value != sorted(set(value)):
            raise ValueError(f"must be increasing, without repeats: {value}")
        return value
