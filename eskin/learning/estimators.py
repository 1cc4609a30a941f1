"""The model registry: each task role's models by name, built from params.

``train.<task>.model`` names an entry of ``REGISTRY[role]`` (or one per kind of
scene); the hyperparameters of model ``m`` sit beside it under ``train.<task>.m``
so that switching models (``dvc exp run -S train.force.model=random_forest``)
needs no other change. Every role has an entry named
``paper``: the paper's configuration, and the default.

The paper's models (section III): linear regression → stretch; a Gaussian
process with an RBF kernel → force; an RBF SVM → contact detection; random
forests → x and y. The paper does not give their hyperparameters; ours are
scikit-learn's defaults plus what the data need — inputs standardised before
the kernel methods (an RBF on raw ADC counts is meaningless), a white-noise
term in the GP kernel (the readings are noisy), and balanced class weights
in the SVM (the paper: SVMs "can be adjusted to compensate for imbalances").
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping
from functools import partial
from typing import Any

import numpy as np
from sklearn.base import (
    BaseEstimator,
    ClassifierMixin,
    RegressorMixin,
    TransformerMixin,
    clone,
)
from sklearn.dummy import DummyClassifier
from sklearn.ensemble import (
    ExtraTreesClassifier,
    HistGradientBoostingClassifier,
    HistGradientBoostingRegressor,
    RandomForestClassifier,
    RandomForestRegressor,
)
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.linear_model import LinearRegression, LogisticRegression, Ridge
from sklearn.neighbors import KNeighborsClassifier
from sklearn.pipeline import Pipeline, make_pipeline
from sklearn.preprocessing import FunctionTransformer, StandardScaler
from sklearn.svm import SVC, LinearSVC
from sklearn.utils.validation import check_is_fitted, validate_data

from eskin.learning.choice import ROW_COLUMN_MODELS
from eskin.learning.gp import (
    FixedKernelGaussianProcess,
    SparseGaussianProcess,
    rbf_gp_kernel,
    subsample_rows,
)
from eskin.skin import AnySkin, Skin, skin_of_columns

ROLES = ("stretch", "force", "detect", "localise")


class SubsampledGaussianProcess(RegressorMixin, BaseEstimator):
    """An exact RBF Gaussian process fitted on a stratified subsample.

    The paper fits a GP on each training fold; scikit-learn's exact GP costs
    O(n³) per optimiser step, so on a ~22,000-sample fold it does not finish
    here. This estimator draws ``subsample`` training samples, stratified on
    the target's levels when the target is discrete, optimises the kernel's
    hyperparameters and conditions on them, and predicts any number of
    samples. Inputs are standardised and the target normalised inside.

    Parameters
    ----------
    subsample : int
        Training samples kept (all of them when there are fewer).
    n_restarts_optimizer : int
        Extra random starts of the hyperparameter optimiser.
    random_state : int
        Seeds the subsample and the restarts.
    """

    def __init__(self, subsample: int = 2000, n_restarts_optimizer: int = 0,
                 random_state: int = 0) -> None:
        self.subsample = subsample
        self.n_restarts_optimizer = n_restarts_optimizer
        self.random_state = random_state

    def fit(self, X, y):  # noqa: N803 - scikit-learn's name
        X, y = validate_data(self, X, y, dtype=np.float64, y_numeric=True)
        if self.subsample < 2:
            raise ValueError(f"subsample must be at least 2, got {self.subsample}")
        self.subsample_index_ = subsample_rows(y, self.subsample, self.random_state)
        self.model_ = make_pipeline(StandardScaler(), GaussianProcessRegressor(
            rbf_gp_kernel(), normalize_y=True, n_restarts_optimizer=self.n_restarts_optimizer,
            random_state=self.random_state))
        with warnings.catch_warnings(record=True) as caught:
            # A hyperparameter at its bound is an outcome to report, not a reason to
            # print the same line once per fold: keep it on the estimator.
            warnings.simplefilter("always", ConvergenceWarning)
            self.model_.fit(X[self.subsample_index_], y[self.subsample_index_])
        self.convergence_warnings_ = sorted({str(w.message).split(". ")[0] for w in caught
                                             if issubclass(w.category, ConvergenceWarning)})
        for other in (w for w in caught if not issubclass(w.category, ConvergenceWarning)):
            warnings.warn_explicit(other.message, other.category, other.filename, other.lineno)
        return self

    def predict(self, X):  # noqa: N803
        check_is_fitted(self)
        X = validate_data(self, X, dtype=np.float64, reset=False)
        return self.model_.predict(X)


def row_column_skin(transformer: BaseEstimator) -> Skin:
    """The row/column skin a fitted transformer reads, from the names of the channels it
    was fitted on: x terminals ``cx1..cxR``, then y terminals ``cy1..cyC``. By name, not
    by a parameter, so that the paper's models pickle as they always have; and a frame
    whose channels are another skin's, or out of order, is refused instead of read."""
    names = [str(name) for name in getattr(transformer, "feature_names_in_", [])]
    try:
        skin = skin_of_columns(names)
    except ValueError:
        skin = None
    if skin is None or skin.channels != names:
        shown = ", ".join(names[:4]) + (", …" if len(names) > 4 else "") or "unnamed columns"
        raise ValueError(f"{type(transformer).__name__} reads a row/column skin's terminals "
                         f"by name (cx1..cxR, then cy1..cyC), got {shown}: fit it on a "
                         "DataFrame of those channels (a channel array takes generic models)")
    return skin


class ActiveTerminals(TransformerMixin, BaseEstimator):
    """The read-out's own view of two contacts: which terminals are pressed, and how hard.

    A row/column (self-capacitance) read-out sees, per axis, the terminals a contact
    lights and by how much; two contacts {(xa, ya), (xb, yb)} and their ghost
    {(xa, yb), (xb, ya)} light the same terminals, and only the amplitudes tell which x
    goes with which y — the harder press is larger on both axes. Per row this adds, per
    axis, the two strongest local peaks of the change from rest (lower terminal first),
    their amplitudes, the log ratio of the two, and whether the two axes' ratios agree
    in sign (the pairing the amplitudes vote for), after the changes themselves.

    The rest reading is each channel's ``rest_quantile`` over the training rows: in a
    two-contact scene a terminal is unpressed in most of them. The axes are told apart by
    the channels' names (:func:`row_column_skin`): fit it on a DataFrame.
    """

    def __init__(self, rest_quantile: float = 0.05) -> None:
        self.rest_quantile = rest_quantile

    def fit(self, X, y=None):  # noqa: N803 - scikit-learn's name
        X = validate_data(self, X, dtype=np.float64)
        row_column_skin(self)
        self.rest_ = np.quantile(X, self.rest_quantile, axis=0)
        # One unit for every channel, so that amplitudes compare across terminals, and
        # the units cancel (counts or farads).
        spread = float(np.median(X.std(axis=0)))
        self.unit_ = spread if spread > 0 else 1.0
        return self

    def transform(self, X):  # noqa: N803
        check_is_fitted(self)
        X = validate_data(self, X, dtype=np.float64, reset=False)
        # rounded as _scaled does: ADC steps tie neighbours exactly, and a tie must break
        # the same way in counts as in farads
        change = np.round((X - self.rest_) / self.unit_, 6)
        x_terminals = row_column_skin(self).rows  # they come first, then the y terminals
        columns, ratios = [change], []
        for axis in (change[:, :x_terminals], change[:, x_terminals:]):
            padded = np.pad(axis, ((0, 0), (1, 1)), constant_values=-np.inf)
            peak = (axis >= padded[:, :-2]) & (axis >= padded[:, 2:])
            ranked = np.argsort(np.where(peak, axis, -np.inf), axis=1, kind="stable")
            top = np.sort(ranked[:, -2:], axis=1)                # (n, 2) lower terminal first
            amplitude = np.take_along_axis(axis, top, axis=1)
            ratio = np.log(np.clip(amplitude[:, 0], 1e-3, None)
                           / np.clip(amplitude[:, 1], 1e-3, None))
            ratios.append(ratio)
            columns += [top.astype(float), amplitude, ratio[:, None]]
        columns.append((np.sign(ratios[0]) == np.sign(ratios[1])).astype(float)[:, None])
        return np.hstack(columns)


# The terminals per axis a press reaches: the one under it and two each way.
PRESS_SPAN = 5


class ForceProfile(TransformerMixin, BaseEstimator):
    """What the physics says a force reading is made of.

    Stretch scales every terminal (C ∝ λ); a press adds to the few terminals under it
    (at most five per axis). So, per row: each terminal in units of its spread at rest
    (mean and SD over the training rows whose target is 0, i.e. without contact: there,
    stretch and drift make the spread); a stretch estimate, the mean of the ``quiet``
    lowest terminals per axis, which a press leaves alone; each terminal's change from
    that rest reading; and per axis the largest change, the sum of the positive changes,
    the sum over the largest and its two neighbours, and where the largest is. A press
    raises the capacitance, so a model may be made monotone in the peaks and sums
    (:meth:`monotone`); a stretched skin is stiffer, which the stretch estimate carries.
    Per-channel units and offsets cancel (counts, volts, farads). The axes, of any R × C
    skin, are told apart by the channels' names (:func:`row_column_skin`): fit it on a
    DataFrame.
    """

    def __init__(self, quiet: int = 3) -> None:
        self.quiet = quiet

    @staticmethod
    def default_quiet(skin: Skin) -> int:
        """The quiet terminals per axis where params set none: those a press leaves alone
        on the shorter axis (it reaches :data:`PRESS_SPAN` terminals), at most 3 (the
        paper's 10 × 10 skin's value) and at least 1 (on a skin a press covers)."""
        return int(np.clip(min(skin.rows, skin.columns) - PRESS_SPAN, 1, 3))

    @staticmethod
    def monotone(skin: Skin) -> list[int]:
        """Per column of :meth:`transform` on ``skin``: +1 where force rises with it, 0 for
        no constraint."""
        return [0] * skin.terminals + [0] + [1, 1, 1, 0] * 2

    def fit(self, X, y=None):  # noqa: N803 - scikit-learn's name
        X = validate_data(self, X, dtype=np.float64)
        skin = row_column_skin(self)
        if not 1 <= self.quiet <= min(skin.rows, skin.columns):
            raise ValueError(f"ForceProfile's quiet terminals per axis must be 1 to "
                             f"{min(skin.rows, skin.columns)} on a {skin.describe()}, got "
                             f"{self.quiet}: set train.force.physics_profile.quiet")
        rest = X if y is None else X[np.asarray(y, dtype=float) == 0]
        if len(rest) < 2 * X.shape[1]:  # too few contact-free rows: every row is rest
            rest = X
        self.rest_mean_ = rest.mean(axis=0)
        spread = rest.std(axis=0)
        self.rest_sd_ = np.where(spread > 0, spread, 1.0)
        return self

    def transform(self, X):  # noqa: N803
        check_is_fitted(self)
        X = validate_data(self, X, dtype=np.float64, reset=False)
        # rounded as _scaled does, so that units and offsets leave no last-bit differences
        level = np.round((X - self.rest_mean_) / self.rest_sd_, 6)
        x_terminals = row_column_skin(self).rows  # they come first, then the y terminals
        axes = (level[:, :x_terminals], level[:, x_terminals:])
        stretch = np.mean([np.sort(a, axis=1)[:, :self.quiet].mean(axis=1) for a in axes],
                          axis=0)
        change = level - stretch[:, None]
        columns = [change, stretch[:, None]]
        for axis in (change[:, :x_terminals], change[:, x_terminals:]):
            top = np.argmax(axis, axis=1)
            padded = np.pad(axis, ((0, 0), (1, 1)))
            rows = np.arange(len(axis))
            around = padded[rows, top] + padded[rows, top + 1] + padded[rows, top + 2]
            columns.append(np.column_stack([axis[rows, top], np.clip(axis, 0, None).sum(1),
                                            around, top.astype(float)]))
        return np.hstack(columns)


class PeakWindow(ClassifierMixin, BaseEstimator):
    """Where one contact lies along one axis of a row/column skin: the terminal that rose
    most, and the pressed node's offset from it, read from the terminals around it.

    A press lights at most :data:`PRESS_SPAN` terminals per axis, so what tells a node
    from its neighbours lies in a window of them. Per row: each channel standardised
    (over the training rows) and rounded as :func:`_scaled` rounds; the axis's highest
    terminal; the ``window`` terminals each way of it (the axis's ends repeated), less the
    axis's level (the mean of its three lowest, which stretch moves and a press leaves
    alone), and the same relative to the highest; how far the highest lies from each end;
    the level; and which terminal is the highest (one column each, so that a node's own
    sensitivity is learnt). A logistic regression reads the offset from those.

    Its cost per row grows with the terminals of one axis, where a multinomial logistic
    regression on every channel grows with the channels times the nodes (a 32 × 32 skin's
    fit cost 37 times a 10 × 10's per row; docs/learning.md). Which axis locates the target
    is learnt: the one whose highest terminal is the node most often. Node numbers are the
    axis's terminals (1 to R).
    """

    def __init__(self, window: int = 2, C: float = 1.0) -> None:  # noqa: N803
        self.window = window
        self.C = C

    def fit(self, X, y):  # noqa: N803 - scikit-learn's name
        X, y = validate_data(self, X, y, dtype=np.float64)
        skin = row_column_skin(self)
        if self.window < 1:
            raise ValueError(f"PeakWindow's window must be 1 or more terminals, got {self.window}")
        node = np.asarray(y, dtype=float)
        if not np.array_equal(node, np.round(node)):
            raise ValueError("PeakWindow reads node numbers (1 to the terminals of an axis), "
                             f"got {node[node != np.round(node)][0]!r}")
        self.classes_ = np.unique(y)
        self.mean_ = X.mean(axis=0)
        spread = X.std(axis=0)
        self.scale_ = np.where(spread > 0, spread, 1.0)
        level = self._level(X)
        axes = ((0, skin.rows), (skin.rows, skin.terminals))
        hits = [np.mean(level[:, a:b].argmax(axis=1) + 1 == node) for a, b in axes]
        self.axis_ = axes[int(np.argmax(hits))]
        peak, features = self._features(level)
        offset = np.clip(node - peak, -self.window - 1, self.window + 1).astype(np.int64)
        # one offset only (every highest terminal its node): nothing for a model to learn
        self.offset_model_ = (DummyClassifier(strategy="most_frequent") if len(set(offset)) < 2
                              else LogisticRegression(C=self.C, max_iter=1000))
        self.offset_model_.fit(features, offset)
        return self

    def _level(self, X: np.ndarray) -> np.ndarray:
        return np.round((X - self.mean_) / self.scale_, 6)

    def _features(self, level: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(node of each row's highest terminal, the offset model's features)."""
        start, stop = self.axis_
        axis = level[:, start:stop]
        width, reach = stop - start, self.window
        top = axis.argmax(axis=1)
        padded = np.pad(axis, ((0, 0), (reach, reach)), mode="edge")
        around = np.take_along_axis(padded, top[:, None] + np.arange(2 * reach + 1), axis=1)
        quiet = min(3, width)
        base = np.sort(axis, axis=1)[:, :quiet].mean(axis=1)
        around = around - base[:, None]
        relative = around / np.clip(around[:, reach:reach + 1], 1e-3, None)
        ends = np.column_stack([np.minimum(top, reach + 1),
                                np.minimum(width - 1 - top, reach + 1)]).astype(float)
        which = (top[:, None] == np.arange(width)).astype(float)
        return top + 1, np.hstack([around, relative, ends, base[:, None], which])

    def predict(self, X):  # noqa: N803
        check_is_fitted(self)
        X = validate_data(self, X, dtype=np.float64, reset=False)
        peak, features = self._features(self._level(X))
        node = peak + self.offset_model_.predict(features)
        # the nearest node that training saw (an offset past the axis's end lands on it)
        nearest = np.abs(self.classes_[None, :].astype(float) - node[:, None]).argmin(axis=1)
        return self.classes_[nearest]


def _scaled(estimator: BaseEstimator) -> Pipeline:
    """Every model sees standardised channels, rounded to 1e-6, whatever their units.

    Trees too: scikit-learn's trees treat a feature whose values differ by less
    than 1e-7 as constant, so capacitance in farads (~1e-11) made every forest
    a stump (`make stress`, case farads: localisation accuracy fell by 0.84).
    The rounding to a millionth of a standard deviation (one ADC step is more
    than 0.002 here) removes the last-bit differences that units and offsets
    leave after standardising (up to 7e-13 for counts + 1e6): without it, a value
    tied with a histogram bin edge of gradient boosting fell on either side,
    moving some force predictions by up to 6 % of the force's spread, and
    logistic regression changed a localisation label.
    """
    return make_pipeline(StandardScaler(), FunctionTransformer(np.round, kw_args={"decimals": 6}),
                         estimator)


def _on_active_terminals(booster: BaseEstimator) -> Pipeline:
    """Two contacts' models: the pressed terminals' places and amplitudes (ActiveTerminals),
    rounded to 1e-6 as :func:`_scaled` rounds, then ``booster``."""
    return make_pipeline(ActiveTerminals(),
                         FunctionTransformer(np.round, kw_args={"decimals": 6}), booster)


def _physics_profile(skin: Skin, max_iter: int = 200, learning_rate: float = 0.1,
                     quiet: int | None = None, monotone: bool = True, seed: int = 0
                     ) -> Pipeline:
    """ForceProfile (``quiet`` unset: :meth:`ForceProfile.default_quiet` of the skin),
    then gradient boosting monotone in the press: one constraint per feature, so built for
    the skin's terminals."""
    if quiet is None:
        quiet = ForceProfile.default_quiet(skin)
    return make_pipeline(ForceProfile(quiet), HistGradientBoostingRegressor(
        max_iter=max_iter, learning_rate=learning_rate, random_state=seed,
        monotonic_cst=ForceProfile.monotone(skin) if monotone else None))


Factory = Callable[..., BaseEstimator]

REGISTRY: dict[str, dict[str, Factory]] = {
    "stretch": {
        "paper": lambda: _scaled(LinearRegression()),
        "ridge": lambda alpha=1.0: _scaled(Ridge(alpha=alpha)),
        "random_forest": lambda n_estimators=100, seed=0: _scaled(RandomForestRegressor(
            n_estimators, random_state=seed, n_jobs=1)),
    },
    "force": {
        "paper": lambda subsample=2000, n_restarts_optimizer=0, seed=0:
            SubsampledGaussianProcess(subsample, n_restarts_optimizer, seed),
        "random_forest": lambda n_estimators=100, min_samples_leaf=1, seed=0:
            _scaled(RandomForestRegressor(n_estimators, min_samples_leaf=min_samples_leaf,
                                          random_state=seed, n_jobs=1)),
        "hist_gradient_boosting": lambda max_iter=200, learning_rate=0.1, seed=0:
            _scaled(HistGradientBoostingRegressor(max_iter=max_iter, learning_rate=learning_rate,
                                                  random_state=seed)),
        "sparse_gp": lambda n_inducing=500, hyper_subsample=500, ard=True, hyperparameters=None,
            seed=0: SparseGaussianProcess(n_inducing, hyper_subsample, ard, hyperparameters, seed),
        "exact_gp": lambda hyper_subsample=2000, ard=False, seed=0:
            FixedKernelGaussianProcess(hyper_subsample, ard, seed),
        # The reading as the physics composes it (ForceProfile), force monotone in the press.
        "physics_profile": _physics_profile,
        # Two contacts: each pressed terminal's place and amplitude (ActiveTerminals), so
        # that one model serves every pair of nodes; large leaves, as a new trial's
        # placement and seating are unlike any one trial seen.
        "active_terminals": lambda max_iter=200, learning_rate=0.1, min_samples_leaf=20,
            seed=0: _on_active_terminals(HistGradientBoostingRegressor(
                max_iter=max_iter, learning_rate=learning_rate,
                min_samples_leaf=min_samples_leaf, random_state=seed)),
    },
    "detect": {
        "paper": lambda C=1.0, gamma="scale", class_weight="balanced":
            _scaled(SVC(C=C, gamma=gamma, class_weight=class_weight)),
        "linear_svm": lambda C=1.0, class_weight="balanced":
            _scaled(LinearSVC(C=C, class_weight=class_weight)),
        "logistic": lambda C=1.0, class_weight="balanced":
            _scaled(LogisticRegression(C=C, class_weight=class_weight, max_iter=1000)),
        "random_forest": lambda n_estimators=100, seed=0: _scaled(RandomForestClassifier(
            n_estimators, random_state=seed, n_jobs=1)),
        "extra_trees": lambda n_estimators=100, seed=0: _scaled(ExtraTreesClassifier(
            n_estimators, random_state=seed, n_jobs=1)),
        "hist_gradient_boosting": lambda max_iter=100, seed=0: _scaled(
            HistGradientBoostingClassifier(max_iter=max_iter, random_state=seed)),
        "knn": lambda n_neighbors=5: _scaled(KNeighborsClassifier(n_neighbors)),
        # Two contacts: how many press, from the pressed terminals (ActiveTerminals); the
        # counts are weighted alike, as a plan has far more pairs than single contacts.
        "active_terminals": lambda max_iter=100, learning_rate=0.1, min_samples_leaf=20,
            seed=0: _on_active_terminals(HistGradientBoostingClassifier(
                max_iter=max_iter, learning_rate=learning_rate,
                min_samples_leaf=min_samples_leaf, class_weight="balanced",
                random_state=seed)),
    },
    "localise": {
        "paper": lambda n_estimators=100, seed=0: _scaled(RandomForestClassifier(
            n_estimators, random_state=seed, n_jobs=1)),
        "extra_trees": lambda n_estimators=100, seed=0: _scaled(ExtraTreesClassifier(
            n_estimators, random_state=seed, n_jobs=1)),
        "hist_gradient_boosting": lambda max_iter=100, seed=0: _scaled(
            HistGradientBoostingClassifier(max_iter=max_iter, random_state=seed)),
        "knn": lambda n_neighbors=5: _scaled(KNeighborsClassifier(n_neighbors)),
        # Newton-Cholesky: a few Newton steps, as a skin has tens of channels (the
        # Hessian is small). The paper skin's CV fits took 0.57 of lbfgs's time, for
        # the same optimum: conditions-CV accuracy within 0.0003 of lbfgs's.
        "logistic": lambda C=1.0: _scaled(LogisticRegression(C=C, max_iter=1000,
                                                             solver="newton-cholesky")),
        "linear_svm": lambda C=1.0: _scaled(LinearSVC(C=C)),
        # One contact on a row/column skin: the highest terminal per axis and the offset
        # from it (PeakWindow), at a cost per row that does not grow with the nodes.
        "peak_window": lambda window=2, C=1.0: PeakWindow(window=window, C=C),
        # Two contacts: find the pressed terminals, pair them by amplitude (ActiveTerminals).
        "active_terminals": lambda max_iter=200, learning_rate=0.1, min_samples_leaf=20,
            seed=0: _on_active_terminals(HistGradientBoostingClassifier(
                max_iter=max_iter, learning_rate=learning_rate,
                min_samples_leaf=min_samples_leaf, random_state=seed)),
    },
}


# Models built for the skin (their factory takes it first): one constraint per feature.
BUILT_FOR_SKIN = ("physics_profile",)


def build_model(role: str, name: str, hyper: Mapping[str, Any] | None = None,
                skin: AnySkin | None = None) -> BaseEstimator:
    """A fresh, unfitted estimator; errors name the role, the model and what is known.
    ``skin``: the skin it will read, which a model built for the skin
    (:data:`BUILT_FOR_SKIN`) needs, and a row/column model requires to be row/column."""
    if role not in REGISTRY:
        raise ValueError(f"unknown task role {role!r}; known: {sorted(REGISTRY)}")
    models = REGISTRY[role]
    if name not in models:
        raise ValueError(f"no {role} model named {name!r}; known: {sorted(models)}")
    if name in ROW_COLUMN_MODELS and skin is not None and not skin.row_column:
        raise ValueError(f"the {role} model {name!r} reads a row/column skin's terminals; "
                         f"an {skin.describe()} has none: use {ROW_COLUMN_MODELS[name]!r}")
    if name in BUILT_FOR_SKIN and skin is None:
        raise ValueError(f"the {role} model {name!r} is built for a skin's terminals: "
                         "give build_model the skin it will read")
    factory = partial(models[name], skin) if name in BUILT_FOR_SKIN else models[name]
    try:
        return clone(factory(**dict(hyper or {})))
    except TypeError as error:
        raise ValueError(f"bad hyperparameters for {role} model {name!r}: {error}") from None
