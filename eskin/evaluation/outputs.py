"""Where a task's scores and out-of-fold predictions are written: JSON with sorted keys
(NaN kept as NaN, a score that could not be computed) and Parquet."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd


def write_json(document: dict, path: Path) -> None:
    """``document`` as indented JSON at ``path`` (its directory made)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(document, indent=2, sort_keys=True, allow_nan=True) + "\n")


def save_predictions(frame: pd.DataFrame, path: Path) -> None:
    """``frame`` as Parquet at ``path`` (its directory made)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    frame.to_parquet(path, index=False)
