"""params.yaml's ``report``: the figures' schemes and resolution."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

from eskin.config.base import Count, Scheme, Section


class Report(Section):
    schemes: Annotated[list[Scheme], Field(min_length=1)]
    plots_scheme: Scheme
    dpi: Count
    page_dpi: Count
