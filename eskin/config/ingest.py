"""params.yaml's ``ingest``: what ingest does with rows it cannot use."""

from __future__ import annotations

from typing import Literal

from eskin.config.base import Section


class Ingest(Section):
    bad_rows: Literal["error", "quarantine"]  # a scene's own bad_rows (scenes.<s>) overrides
