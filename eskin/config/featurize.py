"""params.yaml's ``featurize``: how channels become features."""

from __future__ import annotations

from typing import Literal

from eskin.config.base import Section


class Featurize(Section):
    method: Literal["raw", "standardise", "baseline"]
