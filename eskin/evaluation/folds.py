"""Cross-validation folds, assigned once per scene so that every task shares them.

* ``stratified`` — the paper's ``StratifiedKFold(10, shuffle=True)`` on the
  pressed node (single force) or on the pair of nodes (two forces): every
  fold holds every node in its share.
* ``grouped`` — whole trials held out (``StratifiedGroupKFold`` on the same
  strata, grouped by trial): a trial's 20 samples are near-duplicates, so
  a fold that trains on 18 of them and tests on 2 flatters the score.

Folds are drawn on the whole scene; a task that uses only some rows (say,
localisation on contacts) keeps their fold numbers, so every task and every
model variant is scored on the same splits.
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
from sklearn.model_selection import StratifiedGroupKFold, StratifiedKFold

from eskin.catalog import SCHEMES
from eskin.data.schema import SKIN
from eskin.kinds import get_kind


def strata(frame: pd.DataFrame, kind: str) -> np.ndarray:
    """The stratum of each row: its node (0 for none), or its pair of nodes."""
    return get_kind(kind).strata(frame, SKIN)


def assign_folds(frame: pd.DataFrame, kind: str, scheme: str, n_splits: int,
                 seed: int) -> np.ndarray:
    """Fold number (0..n_splits-1) of every row, where it is a test sample."""
    if scheme not in SCHEMES:
        raise ValueError(f"cv scheme must be one of {SCHEMES}, got {scheme!r}")
    if n_splits < 2:
        raise ValueError(f"cv.folds must be at least 2, got {n_splits}")
    labels = strata(frame, kind)
    groups = frame["trial"].to_numpy()
    n_groups = len(np.unique(groups))
    if scheme == "grouped" and n_groups < n_splits:
        raise ValueError(f"grouped CV with {n_splits} folds needs at least {n_splits} trials; "
                         f"this dataset has {n_groups}")
    if scheme == "stratified" and len(frame) < n_splits:
        raise ValueError(f"{n_splits}-fold CV needs at least {n_splits} samples; "
                         f"this dataset has {len(frame)}")
    folds = np.full(len(frame), -1, dtype=np.int64)
    with warnings.catch_warnings():
        # A stratum smaller than the fold count is legal and common in small scenes;
        # the split is still valid, only less balanced. Say it once, not per call.
        warnings.filterwarnings("ignore", message="The least populated class")
        if scheme == "stratified":
            splitter = StratifiedKFold(n_splits, shuffle=True, random_state=seed)
            splits = splitter.split(np.zeros(len(frame)), labels)
        else:
            splitter = StratifiedGroupKFold(n_splits, shuffle=True, random_state=seed)
            splits = splitter.split(np.zeros(len(frame)), labels, groups)
        try:
            for fold, (_, test) in enumerate(splits):
                folds[test] = fold
        except ValueError as err:  # scikit-learn's words, without the dataset's numbers
            smallest = int(pd.Series(labels).value_counts().min())
            raise ValueError(
                f"{scheme} CV with {n_splits} folds cannot split this dataset ({len(frame)} "
                f"samples, {n_groups} trials, smallest stratum {smallest} sample(s)): {err} "
                "Acquire more samples or lower cv.folds.") from None
    return folds
