"""Cross-validation folds, assigned once per scene so that every task shares them.

* ``stratified`` — the paper's ``StratifiedKFold(10, shuffle=True)`` on the
  pressed node (single force) or on the pair of nodes (two forces): every
  fold holds every node in its share.
* ``conditions`` — whole conditions held out (``StratifiedGroupKFold`` on the same
  strata, grouped by condition: stretch and contacts, every trial of them; a recording
  whose trials each span several conditions, by trial): a trial's
  20 samples are near-duplicates, so a fold that trains on 18 of them and tests on 2
  flatters the score. With one trial per condition (the paper's plan) a held-out trial
  is a condition training never saw: the harder question of the two below.
* ``trials`` — whole trials held out, each of a condition that training has seen in its
  other trials (a scene with ``repeats`` ≥ 2): how well a new recording of a known
  condition is read.

Folds are drawn on the whole scene; a task that uses only some rows (say,
localisation on contacts) keeps their fold numbers, so every task and every
model variant is scored on the same splits.

One fold runner: cross-validation (:func:`eskin.evaluation.crossval.cross_validate`,
and so training and ``eskin reproduce``) and the bench (:mod:`harness.benchmark`) split
a task's rows with :func:`fold_splitter`, a scikit-learn splitter over their fold numbers.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from itertools import islice
from pathlib import Path

import numpy as np
import pandas as pd
from sklearn.model_selection import (
    BaseCrossValidator,
    GroupKFold,
    KFold,
    PredefinedSplit,
    StratifiedGroupKFold,
    StratifiedKFold,
)
from sklearn.utils.validation import _num_samples

from eskin.catalog import SCHEMES
from eskin.kinds import get_kind
from eskin.skin import AnySkin


def strata(frame: pd.DataFrame, kind: str, skin: AnySkin) -> np.ndarray:
    """The stratum of each row: its node of ``skin`` (0 for none), or its pair of nodes."""
    return get_kind(kind).strata(frame, skin)


def conditions(frame: pd.DataFrame, kind: str) -> np.ndarray:
    """Each row's condition (0, 1, ...): its labels (stretch and every contact's force and
    node), which every sample of a planned trial shares."""
    return frame.groupby(get_kind(kind).labels, sort=False, dropna=False).ngroup().to_numpy()


def trial_conditions(frame: pd.DataFrame, kind: str) -> pd.DataFrame:
    """Each (trial, condition) pair of ``frame`` once, in the order first met: a trial of
    a planned scene is one condition, a trial of a recording read by file may be several."""
    return pd.DataFrame({"trial": frame["trial"].to_numpy(),
                         "condition": conditions(frame, kind)}).drop_duplicates()


def condition_groups(frame: pd.DataFrame, kind: str) -> np.ndarray:
    """Each row's group under the ``conditions`` scheme: its condition, named by the first of
    the condition's trials (so with one trial per condition the groups are the trials, and
    the folds those of grouping by trial). A recording whose trials span several
    conditions (an import read by file or by time, its labels changing within a trial)
    has no condition to a trial: its trials are the groups, held out whole."""
    trial = frame["trial"].reset_index(drop=True)
    if trial_conditions(frame, kind)["trial"].duplicated().any():
        return trial.to_numpy()
    return trial.groupby(conditions(frame, kind)).transform("min").to_numpy()


def _trial_folds(frame: pd.DataFrame, kind: str, n_splits: int, seed: int) -> np.ndarray:
    """The ``trials`` scheme: each condition's trials dealt to distinct folds in turn, from
    a seeded fold, in a seeded order; so no fold holds every trial of a condition."""
    table = trial_conditions(frame, kind)
    mixed = table["trial"].duplicated(keep=False)
    if mixed.any():
        raise ValueError(f"trials CV: trial {table['trial'][mixed].iloc[0]} holds several "
                         "conditions (stretch and contacts); each trial must be one condition")
    trials_per_condition = table.groupby("condition").size()
    single = int((trials_per_condition < 2).sum())
    if single:
        raise ValueError(f"trials CV holds out trials of conditions that training has seen: "
                         f"{single} of {len(trials_per_condition)} conditions have one "
                         "trial; record each at least twice (scenes.<scene>.repeats: 2)")
    rng = np.random.default_rng(seed)
    table = table.sort_values(["condition", "trial"]).reset_index(drop=True)
    table["order"] = rng.random(len(table))
    table = table.sort_values(["condition", "order"])
    start = rng.integers(n_splits, size=table["condition"].max() + 1)
    dealt = (start[table["condition"]] + table.groupby("condition").cumcount()) % n_splits
    fold_of_trial = pd.Series(dealt.to_numpy(), index=table["trial"].to_numpy())
    return fold_of_trial[frame["trial"].to_numpy()].to_numpy(dtype=np.int64)


def repeated_conditions(frame: pd.DataFrame, kind: str) -> bool:
    """Whether every trial of ``frame`` is one condition and every condition has two trials
    or more: what the ``trials`` scheme needs."""
    table = trial_conditions(frame, kind)
    return (bool(len(table)) and not table["trial"].duplicated().any()
            and int(table.groupby("condition").size().min()) >= 2)


def applicable_schemes(frame: pd.DataFrame, kind: str, schemes: list[str]) -> list[str]:
    """``schemes`` (cv.schemes) less ``trials`` where a condition was recorded only once: a
    scene of the paper's plan (``repeats: 1``) is scored under the others, not refused."""
    return [s for s in schemes if s != "trials" or repeated_conditions(frame, kind)]


def coarser_strata(frame: pd.DataFrame, kind: str, skin: AnySkin):
    """Coarser strata than :func:`strata`, finest first, each as (what it is, a stratum per
    row): each contact's node taken in blocks of 2 × 2 nodes, 4 × 4, … up to the whole
    skin (pressed or not). What a split falls back to where every node (or pair) has fewer
    rows than folds."""
    positions = list(get_kind(kind).positions.values())
    block, previous = 2, None
    while True:
        size_x, size_y = -(-skin.size_x // block), -(-skin.size_y // block)
        out = np.zeros(len(frame), dtype=np.int64)
        for x, y in positions:
            bx = np.where(frame[x].to_numpy() > 0, (frame[x].to_numpy(np.int64) - 1) // block, -1)
            by = (frame[y].to_numpy(np.int64) - 1) // block
            node = np.where(bx >= 0, bx * size_y + by + 1, 0)
            out = out * (size_x * size_y + 1) + node
        whole = size_x == 1 and size_y == 1
        what = "pressed or not" if whole else f"{block} × {block}-node blocks"
        if len(np.unique(out)) > 1 and (previous is None
                                        or len(np.unique(out)) < len(np.unique(previous))):
            yield what, out
        if whole:
            return
        block, previous = block * 2, out


def _split(scheme: str, n_splits: int, seed: int, labels: np.ndarray | None,
           groups: np.ndarray) -> np.ndarray:
    """Fold number of each row under ``scheme``'s splitter: stratified on ``labels``, or
    (``labels`` None) unstratified; raises scikit-learn's ValueError where it cannot."""
    rows = np.zeros(len(groups))
    if scheme == "stratified":
        splitter = (StratifiedKFold if labels is not None else KFold)(
            n_splits, shuffle=True, random_state=seed)
        splits = splitter.split(rows, labels)
    else:
        splitter = (StratifiedGroupKFold if labels is not None else GroupKFold)(
            n_splits, shuffle=True, random_state=seed)
        splits = splitter.split(rows, labels, groups)
    folds = np.full(len(groups), -1, dtype=np.int64)
    with warnings.catch_warnings():
        # A stratum smaller than the fold count is legal and common in small scenes;
        # the split is still valid, only less balanced. Say it once, not per call.
        warnings.filterwarnings("ignore", message="The least populated class")
        for fold, (_, test) in enumerate(splits):
            folds[test] = fold
    return folds


def draw_folds(frame: pd.DataFrame, kind: str, scheme: str, n_splits: int,
               seed: int, *, skin: AnySkin) -> tuple[np.ndarray, str]:
    """Fold number (0..n_splits-1) of every row (on ``skin``), where it is a test sample,
    and a note: empty where the scheme split on its own strata (the node, or the pair of
    nodes), else how it fell back and why. Where every node has fewer rows than folds
    (a large skin sampled once), stratification falls back to coarser strata
    (:func:`coarser_strata`), then to none (``KFold``, ``GroupKFold``), each seeded with
    ``seed``. A dataset with fewer rows (or conditions) than folds is refused."""
    if scheme not in SCHEMES:
        raise ValueError(f"cv scheme must be one of {SCHEMES}, got {scheme!r}")
    if n_splits < 2:
        raise ValueError(f"cv.folds must be at least 2, got {n_splits}")
    if scheme == "trials":
        return _trial_folds(frame, kind, n_splits, seed), ""
    labels = strata(frame, kind, skin)
    groups = condition_groups(frame, kind) if scheme == "conditions" else frame["trial"].to_numpy()
    n_groups = len(np.unique(groups))
    if scheme == "conditions" and n_groups < n_splits:
        raise ValueError(f"conditions CV with {n_splits} folds needs at least {n_splits} "
                         f"conditions; this dataset has {n_groups}: lower cv.folds to "
                         f"{max(n_groups, 2)} or acquire more conditions")
    if scheme == "stratified" and len(frame) < n_splits:
        raise ValueError(f"{n_splits}-fold CV needs at least {n_splits} samples; "
                         f"this dataset has {len(frame)}: lower cv.folds or acquire more")
    try:
        return _split(scheme, n_splits, seed, labels, groups), ""
    except ValueError as err:  # every stratum smaller than the folds: coarser ones follow
        refused = err  # scikit-learn's words, said with the dataset's numbers if all fail
    largest = int(pd.Series(labels).value_counts().max())
    node = "pair of nodes" if len(get_kind(kind).positions) > 1 else "node"
    why = (f"every {node} has fewer rows than the {n_splits} folds (at most {largest}); "
           "more samples per condition, or fewer folds, keeps the node strata")
    for what, coarse in [*coarser_strata(frame, kind, skin), ("nothing", None)]:
        try:
            folds = _split(scheme, n_splits, seed, coarse, groups)
        except ValueError:
            continue
        how = "not stratified" if coarse is None else f"stratified on {what}"
        return folds, f"{how}, not on the {node}: {why}"
    smallest = int(pd.Series(labels).value_counts().min())
    raise ValueError(
        f"{scheme} CV with {n_splits} folds cannot split this dataset ({len(frame)} "
        f"samples, {n_groups} trials, smallest stratum {smallest} sample(s)): {refused} "
        "Acquire more samples or lower cv.folds.")


def assign_folds(frame: pd.DataFrame, kind: str, scheme: str, n_splits: int,
                 seed: int, *, skin: AnySkin) -> np.ndarray:
    """Fold number (0..n_splits-1) of every row (on ``skin``), where it is a test sample
    (:func:`draw_folds`, without its note)."""
    return draw_folds(frame, kind, scheme, n_splits, seed, skin=skin)[0]


class FoldSplit(BaseCrossValidator):
    """A scikit-learn splitter over fold numbers: :class:`~sklearn.model_selection.PredefinedSplit`,
    optionally cut to its first ``n_folds`` folds (the bench scores ``bench.evaluate_folds``).

    ``test_fold``: a fold number per row, -1 for a row no fold tests. Folds come in
    increasing order of their number; each tests the rows of that number and trains on
    every other row, rows of -1 included — as PredefinedSplit does, and as the loops over
    ``fold_of != fold`` that this replaced did. A negative number other than -1 is
    refused: PredefinedSplit would test it as a fold, those loops skipped it.
    """

    def __init__(self, test_fold, n_folds: int | None = None):
        self.test_fold = np.asarray(test_fold)
        self.n_folds = n_folds
        if self.test_fold.ndim != 1:
            raise ValueError(f"fold numbers must be one per row, got shape {self.test_fold.shape}")
        if (self.test_fold < -1).any():
            raise ValueError("fold numbers must be -1 (never tested) or 0 and above, "
                             f"got {int(self.test_fold.min())}")
        if n_folds is not None and n_folds < 1:
            raise ValueError(f"n_folds must be at least 1 (or None for all), got {n_folds}")

    def _predefined(self) -> PredefinedSplit:
        # Made when asked, not kept: a splitter sent to a cluster's workers carries the
        # fold numbers once.
        return PredefinedSplit(self.test_fold)

    def get_n_splits(self, X=None, y=None, groups=None) -> int:
        n = self._predefined().get_n_splits()
        return n if self.n_folds is None else min(n, self.n_folds)

    def split(self, X=None, y=None, groups=None):
        """(train, test) row indices of each fold, in increasing fold number."""
        if X is not None and _num_samples(X) != len(self.test_fold):
            raise ValueError(f"X has {_num_samples(X)} rows, the fold numbers "
                             f"{len(self.test_fold)}")
        # groups: the folds are given, so there is nothing to group (PredefinedSplit would
        # warn that it ignores them; cross_val_score passes None).
        return islice(self._predefined().split(), self.get_n_splits())

    def fold(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(train, test) of the ``k``-th split (0-based), as :meth:`split` yields it: what a
        worker that holds the splitter computes from a fold's position alone."""
        if not 0 <= k < self.get_n_splits():
            raise IndexError(f"fold {k} of {self.get_n_splits()}")
        return next(islice(self._predefined().split(), k, None))


def fold_splitter(fold_of: np.ndarray, n_folds: int | None = None) -> FoldSplit:
    """The splitter over a task's rows given their fold numbers (``assign_folds``' array
    restricted to the task's rows): every fold, or the first ``n_folds``."""
    return FoldSplit(fold_of, n_folds)


@dataclass(frozen=True)
class SceneFolds:
    """Every scheme's fold numbers for a scene's rows (:func:`draw_scene_folds`)."""

    # one column per scheme drawn, beside the row's trial; a scheme that fell back
    # (:func:`draw_folds`) says how in ``attrs["fold_notes"]`` (absent where none did,
    # so such files keep their bytes; :func:`read_fold_notes`)
    table: pd.DataFrame
    summary: str


def draw_scene_folds(frame: pd.DataFrame, kind: str, skin: AnySkin, *, schemes: list[str],
                     n_splits: int, seed: int, scene: str, where: str = "") -> SceneFolds:
    """Every scheme's fold numbers for ``frame``'s rows, drawn once (the folds step,
    :mod:`eskin.steps.folds`, writes them): one column per scheme, in ``schemes``' order,
    beside the row's trial (checked by :func:`read_scene_folds`). Every task and model
    variant of the scene reads them. ``where`` (the features' path) goes into errors."""
    columns = {"trial": frame["trial"].to_numpy()}
    notes: dict[str, str] = {}
    drawn = applicable_schemes(frame, kind, schemes)
    for scheme in drawn:
        try:
            columns[scheme], note = draw_folds(frame, kind, scheme, n_splits, seed, skin=skin)
        except ValueError as err:
            raise ValueError(f"scenes.{scene} ({where}): {err}") from None
        if note:
            notes[scheme] = note
    table = pd.DataFrame(columns)
    if notes:
        table.attrs["fold_notes"] = notes
    left = [s for s in schemes if s not in drawn]
    return SceneFolds(table, (
        f"{scene}: {n_splits} folds of {len(frame):,} rows, "
        f"{len(np.unique(columns['trial'])):,} trials, for {', '.join(drawn)} CV"
        + (f"; not {', '.join(left)}: a condition has only one trial (or a trial "
           f"several conditions); scenes.{scene}.repeats: 2 or more allows it"
           if left else "")
        + "".join(f"; {' and '.join(s for s in notes if notes[s] == note)} CV {note}"
                  for note in dict.fromkeys(notes.values()))))


def read_fold_notes(path: Path) -> dict[str, str]:
    """How each scheme of the folds file at ``path`` fell back from its node strata, by
    scheme (:func:`draw_folds`); empty where none did."""
    return dict(pd.read_parquet(path, columns=["trial"]).attrs.get("fold_notes", {}))


def read_scene_folds(path: Path, frame: pd.DataFrame) -> dict[str, np.ndarray]:
    """The fold numbers of ``frame``'s rows by scheme, as the folds step drew them for
    these very rows (same count, same trials, in order)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no folds; run `dvc repro prepare@{path.stem}` first")
    folds = pd.read_parquet(path)
    if len(folds) != len(frame) or not np.array_equal(folds["trial"].to_numpy(),
                                                      frame["trial"].to_numpy()):
        raise ValueError(f"{path}: its {len(folds):,} rows are not the features' "
                         f"{len(frame):,} rows in order; run `dvc repro prepare@{path.stem}`")
    return {scheme: folds[scheme].to_numpy() for scheme in folds.columns if scheme != "trial"}
