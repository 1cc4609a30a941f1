"""params.yaml's ``live``: `eskin live`'s knobs (and make bench's live hour); no stage of
`dvc repro` reads them."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from eskin.config.base import NonNegative, Positive, Section, real


class LiveBaseline(Section):
    """How `eskin live` follows a board's offset from the training's untouched readings
    after the tare (eskin/deploy/live.py)."""

    time_constant_s: NonNegative = 0.5   # 0: the tare's offset, never followed
    gate_counts: Positive = 8.0          # a frame updates it only if no channel moved more
    # in contact: freeze it, or follow the channels the contact leaves within the gate
    in_contact: Literal["freeze", "quiet_channels"] = "freeze"
    reach_terminals: Annotated[int, Field(ge=0)] = 2  # quiet_channels: frozen each side of it


class LiveContact(Section):
    """Contact with hysteresis, on the stack's contact probability (eskin/deploy/live.py)."""

    enter_probability: real(gt=0, le=1) = 0.8
    leave_probability: real(ge=0, lt=1) = 0.5
    min_duration_ms: NonNegative = 50.0

    @model_validator(mode="after")
    def _ordered(self) -> LiveContact:
        if self.leave_probability > self.enter_probability:
            raise ValueError(f"leave_probability ({self.leave_probability}) is above "
                             f"enter_probability ({self.enter_probability}): contact would "
                             "end before it began")
        return self


class Live(Section):
    """`eskin live`'s knobs (and make bench's live hour): not read by `dvc repro`. The
    defaults are params.yaml's, for the library's callers that pass none."""

    tare_frames: Annotated[int, Field(ge=0)] = 100
    baseline: LiveBaseline = LiveBaseline()
    contact: LiveContact = LiveContact()
