"""params.yaml's ``live``: `eskin live`'s knobs (and make bench's live hour); no stage of
`dvc repro` reads them."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from eskin.config.base import NonNegative, Positive, Section, real


class LiveBaseline(Section):
    """How `eskin live` follows a board's offset from the training's untouched readings
    after the tare (eskin/deploy/live.py)."""

    time_constant_s: NonNegative = 20.0  # 0: the tare's offset, never followed
    gate_counts: Positive = 8.0          # a frame updates it only if no channel moved more
    # in contact: follow all but the contact's channels (contact_channels), freeze it
    # wholly, or follow the channels the contact leaves within the gate (quiet_channels)
    in_contact: Literal["contact_channels", "freeze", "quiet_channels"] = "contact_channels"
    reach_terminals: Annotated[int, Field(ge=0)] = 2  # the contact's: this far each side of it
    fallen_counts: Positive = 2.0        # contact_channels: a contact's channel this far below
    # its expected reading is followed back (no press lowers a reading) ...
    drift_counts_per_sqrt_s: NonNegative = 0.5  # ... and, once its press lifted, what is
    # left within the drift a freeze of this long may have missed (0: never)
    frozen_first_s: NonNegative = 10.0   # contact_channels: a press's first seconds (one
    # of its channels beyond the gate), frozen whole: the drift they may hide is a count
    lift_average_s: NonNegative = 0.25   # contact_channels: the contact's summed rise,
    # averaged over this long, is judged against half its peak (the press lifted) ...
    lifted_time_constant_s: NonNegative = 0.5  # ... and what a lifted press left is
    # followed this fast (drift the freeze missed: a phantom until it is)


class LiveContact(Section):
    """Contact with hysteresis, on the stack's contact probability (eskin/deploy/live.py)."""

    enter_probability: real(gt=0, le=1) = 0.8
    leave_probability: real(ge=0, lt=1) = 0.5
    min_duration_ms: NonNegative = 25.0

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
