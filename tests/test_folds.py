"""One fold runner (issue 36, item 4): a scikit-learn splitter over the scene's fold numbers,
yielding the folds the loops over ``fold_of != fold`` yielded, used by CV and the bench."""

import numpy as np
import pandas as pd
import pytest
from sklearn.base import clone
from sklearn.linear_model import Ridge
from sklearn.metrics import r2_score
from sklearn.model_selection import check_cv, cross_val_score
from sklearn.model_selection import cross_validate as sklearn_cross_validate
from sklearn.neighbors import KNeighborsRegressor

from eskin.evaluation.crossval import cross_validate
from eskin.evaluation.folds import FoldSplit, fold_splitter
from eskin.evaluation.tasks import Task
from eskin.skin import PAPER_SKIN
from harness import benchmark

CHANNELS = PAPER_SKIN.channels

# Fold numbers with rows no fold tests (-1), folds out of order and a gap (no 3..8).
FOLDS = np.array([2, 0, 1, -1, 2, 9, 1, 0, -1, 2, 0, 1, 2, 9, 0, -1, 1, 2, 0, 1,
                  -1, 2, 0, 9, 1, 2, -1, 0, 1, 2])


def old_loop(fold_of, n_folds=None):
    """The fold runner this replaced (crossval.cross_validate, benchmark.run_variant)."""
    fold_ids = [f for f in np.unique(fold_of) if f >= 0][:n_folds]
    return [(np.flatnonzero(fold_of != f), np.flatnonzero(fold_of == f)) for f in fold_ids]


@pytest.mark.parametrize("n_folds", [None, 1, 2, 4, 10])
def test_the_splitter_yields_the_old_loops_folds(n_folds):
    """Same (train, test) arrays in the same order: rows of -1 are trained on, never tested."""
    splitter = fold_splitter(FOLDS, n_folds)
    expected = old_loop(FOLDS, n_folds)
    got = list(splitter.split(np.zeros((len(FOLDS), 3))))
    assert splitter.get_n_splits() == len(expected) == len(got)
    for k, ((train, test), (old_train, old_test)) in enumerate(zip(got, expected, strict=True)):
        assert train.dtype == old_train.dtype and test.dtype == old_test.dtype
        assert np.array_equal(train, old_train) and np.array_equal(test, old_test)
        assert set(np.flatnonzero(FOLDS == -1)) <= set(train)
        assert all(np.array_equal(a, b) for a, b in zip(splitter.fold(k), (train, test),
                                                           strict=True))
    assert [FOLDS[test][0] for _, test in got] == [0, 1, 2, 9][:len(got)]


def test_the_splitter_refuses_what_the_old_loop_would_have_read_differently():
    with pytest.raises(ValueError, match="-1"):
        fold_splitter(np.array([0, 1, -2, 1]))
    with pytest.raises(ValueError, match="rows"):
        list(fold_splitter(FOLDS).split(np.zeros((len(FOLDS) - 1, 2))))
    with pytest.raises(IndexError):
        fold_splitter(FOLDS, 2).fold(2)


def test_scikit_learn_takes_it_as_a_splitter():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(len(FOLDS), 4))
    y = X @ np.array([1.0, -2.0, 0.5, 0.0]) + 0.1 * rng.normal(size=len(FOLDS))
    splitter = fold_splitter(FOLDS, 3)
    assert check_cv(splitter) is splitter
    assert "FoldSplit(" in repr(splitter)
    by_hand = [r2_score(y[test], clone(Ridge()).fit(X[train], y[train]).predict(X[test]))
               for train, test in old_loop(FOLDS, 3)]
    assert np.array_equal(cross_val_score(Ridge(), X, y, cv=splitter), by_hand)
    result = sklearn_cross_validate(Ridge(), X, y, cv=splitter, return_indices=True)
    assert [t.tolist() for t in result["indices"]["test"]] == \
        [t.tolist() for _, t in old_loop(FOLDS, 3)]


def synthetic():
    """A task on 25 of 30 rows; 1-nearest-neighbour predictions name the training row they
    came from (targets are distinct), so a row trained on or not changes them."""
    rng = np.random.default_rng(36)
    n = len(FOLDS)
    frame = pd.DataFrame(rng.normal(size=(n, len(CHANNELS))), columns=CHANNELS)
    frame["target"] = np.arange(n, dtype=float) * 1.5
    frame["keep"] = np.arange(n) % 6 != 5
    task = Task("synthetic", "force", "regression", {"target": lambda f: f["target"].to_numpy()},
                rows=lambda f: f["keep"].to_numpy())
    return task, frame


# Computed with the fold loops this replaced (crossval.cross_validate and
# benchmark.run_variant/bound_scores before issue 36 item 4), on synthetic() and FOLDS.
NA = None
EXPECTED_OOF = [27.0, 42.0, 27.0, NA, 40.5, 27.0, 42.0, NA, 39.0, 31.5, 27.0, 22.5, 0.0, NA,
                0.0, 18.0, 15.0, NA, 4.5, 31.5, 19.5, 22.5, NA, 22.5, 1.5]
EXPECTED_FOLD = [2, 0, 1, -1, 2, 1, 0, -1, 2, 0, 2, 9, 0, -1, 1, 0, 1, -1, 2, 0, 1, 2, -1, 0, 1]
EXPECTED_FOLD_MAE = [19.714285714285715, 22.75, 23.0, 3.0]
EXPECTED_VARIANT = {"r2": -2.274505252753297, "mse": 565.6339285714286,
                    "mae": 21.232142857142858, "mae_std": 1.5178571428571423}
EXPECTED_BOUND = {"r2": -3.0792397497754864, "mse": 710.25, "mae": 23.25, "mae_std": 2.25}


def test_out_of_fold_predictions_are_those_of_the_old_fold_loop():
    task, frame = synthetic()
    result = cross_validate(task, frame, FOLDS, KNeighborsRegressor(n_neighbors=1),
                            "stratified", PAPER_SKIN)
    predicted = [None if pd.isna(v) else float(v) for v in result.predictions["target_pred"]]
    assert predicted == EXPECTED_OOF
    assert result.predictions["fold"].tolist() == EXPECTED_FOLD
    assert [fold["mae"] for fold in result.per_fold["target"]] == EXPECTED_FOLD_MAE


def test_the_bench_scores_the_old_fold_loops_folds():
    task, frame = synthetic()
    rows = task.rows(frame)
    data = frame[rows].reset_index(drop=True)
    splitter = fold_splitter(FOLDS[rows], 2)
    scores = benchmark.run_variant(task, data, splitter, KNeighborsRegressor(n_neighbors=1),
                                   False, skin=PAPER_SKIN)["scores"]["target"]
    for name, value in EXPECTED_VARIANT.items():
        assert scores[name] == pytest.approx(value, rel=1e-12)
    oracle = pd.DataFrame({"target": data["target"].to_numpy()[::-1].copy()})
    bound = benchmark.bound_scores(task, data, oracle, splitter)["target"]
    for name, value in EXPECTED_BOUND.items():
        assert bound[name] == pytest.approx(value, rel=1e-12)


def test_cv_and_the_bench_run_their_folds_through_the_splitter(monkeypatch):
    """No second fold runner: the bench runs a variant's folds through cross_validate, which
    takes each fold's (train, test) from FoldSplit, the bench's first folds only."""
    from eskin.evaluation import crossval

    task, frame = synthetic()
    calls = []
    fold, run = FoldSplit.fold, crossval.cross_validate
    monkeypatch.setattr(FoldSplit, "fold", lambda self, k: calls.append("fold")
                        or fold(self, k))
    monkeypatch.setattr(benchmark, "cross_validate", lambda *a, **k: calls.append("cv")
                        or run(*a, **k))
    cross_validate(task, frame, FOLDS, KNeighborsRegressor(n_neighbors=1), "stratified",
                   PAPER_SKIN)
    assert calls == ["fold"] * 4
    calls.clear()
    rows = task.rows(frame)
    data = frame[rows].reset_index(drop=True)
    benchmark.run_variant(task, data, fold_splitter(FOLDS[rows], 2),
                          KNeighborsRegressor(n_neighbors=1), False, skin=PAPER_SKIN)
    assert calls == ["cv", "fold", "fold"]
