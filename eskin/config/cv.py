"""params.yaml's ``cv``: the cross-validation every task is scored by."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

from eskin.config.base import Backend, Jobs, Scheme, Section, Seed


class CV(Section):
    schemes: Annotated[list[Scheme], Field(min_length=1)]
    folds: Annotated[int, Field(ge=2)]
    seed: Seed
    n_jobs: Jobs
    backend: Backend
