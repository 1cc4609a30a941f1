"""Gaussian processes that scale to a full training fold.

:class:`SparseGaussianProcess` is an RBF Gaussian process with one length
scale per channel (ARD), conditioned on all n training samples through m
inducing points (the subset-of-regressors / Nyström predictive mean). Its
hyperparameters are fitted by scikit-learn's exact GP on a small subsample
(or given, to reuse them across folds); conditioning then costs O(n m²)
instead of O(n³), so doubling the data doubles the cost.

:func:`stable_cholesky` factorises a kernel matrix with as little jitter as
works: repeated or collinear samples make kernel matrices singular in exact
arithmetic, and a fixed jitter either fails on them or blurs the rest.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping

import numpy as np
from scipy.linalg import LinAlgError, cho_solve, cholesky, solve_triangular
from sklearn.base import BaseEstimator, RegressorMixin
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel
from sklearn.model_selection import train_test_split
from sklearn.utils.validation import check_is_fitted, check_random_state, validate_data
from threadpoolctl import threadpool_limits

SINGLE_THREAD_FROM = 4096  # matrix order from which the factorisation runs on one BLAS thread


def stable_cholesky(matrix: np.ndarray, *, max_tries: int = 8) -> tuple[np.ndarray, float]:
    """Lower Cholesky factor of a symmetric PSD matrix, adding jitter only if needed.

    Jitter starts at 1e-10 × the mean diagonal and grows tenfold per failure;
    returns (factor, jitter used). Raises ``LinAlgError`` naming the jitter
    tried when even the largest does not make the matrix positive definite
    (a NaN in the input, for instance).
    """
    if not np.all(np.isfinite(matrix)):
        raise LinAlgError("kernel matrix has NaN or infinite entries")
    scale = float(np.mean(np.diag(matrix))) or 1.0
    jitter = 0.0
    diagonal = np.diag_indices_from(matrix)
    # OpenBLAS 0.3.30's threaded dpotrf (SciPy's wheel) segfaults on this machine from
    # n ≈ 16,000 with two threads (OpenBLAS issues #2562, #2821); one thread does not.
    threads = 1 if len(matrix) >= SINGLE_THREAD_FROM else None
    for attempt in range(max_tries + 1):
        try:
            with threadpool_limits(threads, user_api="blas"):
                if jitter:  # a copy, not matrix + jitter·I: no second n × n temporary
                    jittered = matrix.copy()
                    jittered[diagonal] += jitter
                    return cholesky(jittered, lower=True, overwrite_a=True,
                                    check_finite=False), jitter
                return cholesky(matrix, lower=True, check_finite=False), jitter
        except LinAlgError:
            jitter = scale * 1e-10 * 10.0 ** attempt
    raise LinAlgError(f"kernel matrix not positive definite even with jitter {jitter:.1e}")


def subsample_rows(y: np.ndarray, size: int, random_state) -> np.ndarray:
    """``size`` row indices, stratified on y's levels when y is discrete enough to allow it."""
    rows = np.arange(len(y))
    if len(y) <= size:
        return rows
    levels, counts = np.unique(y, return_counts=True)
    stratify = y if len(levels) <= size // 2 and counts.min() >= 2 else None
    chosen, _ = train_test_split(rows, train_size=size, stratify=stratify,
                                 random_state=random_state)
    return np.sort(chosen)


def rbf_gp_kernel(length_scale=1.0, noise_level: float = 0.1):
    """Signal variance × RBF (one length scale, or one per input) + white noise."""
    return (ConstantKernel(1.0, (1e-3, 1e3)) * RBF(length_scale, (1e-2, 1e3))
            + WhiteKernel(noise_level, (1e-6, 1e1)))


def fit_rbf_hyperparameters(X: np.ndarray, y: np.ndarray, *, ard: bool,  # noqa: N803
                            random_state: int = 0) -> tuple[dict[str, object], list[str]]:
    """Signal variance, length scale(s) and noise of an RBF GP by maximum marginal likelihood.

    ``X`` and ``y`` are standardised already. Returns the hyperparameters and
    the optimiser's convergence messages (a hyperparameter at its bound).
    """
    kernel = rbf_gp_kernel(np.ones(X.shape[1]) if ard else 1.0)
    gp = GaussianProcessRegressor(kernel, normalize_y=False, random_state=random_state)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConvergenceWarning)
        gp.fit(X, y)
    notes = sorted({str(w.message).split(". ")[0] for w in caught
                    if issubclass(w.category, ConvergenceWarning)})
    fitted = gp.kernel_
    hyper = {"signal_variance": float(fitted.k1.k1.constant_value),
             "length_scale": np.atleast_1d(fitted.k1.k2.length_scale).astype(float).tolist(),
             "noise_variance": float(fitted.k2.noise_level)}
    return hyper, notes


class _StandardisedRBF(RegressorMixin, BaseEstimator):
    """What both GPs share: standardised inputs and target, the RBF kernel, blocked prediction.

    Subclasses fit ``centres_`` (points in length-scale units) and ``weights_``;
    the prediction is ``k(x, centres_) @ weights_``, back in the target's units.
    """

    _block = 8192  # query rows per kernel block: bounded memory for any number of queries

    def _standardise(self, X: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self.x_mean_ = X.mean(axis=0)
        x_std = X.std(axis=0)
        self.x_scale_ = np.where(x_std > 0, x_std, 1.0)  # a dead channel stays zero
        self.y_mean_ = float(y.mean())
        self.y_scale_ = float(y.std()) or 1.0
        return (X - self.x_mean_) / self.x_scale_, (y - self.y_mean_) / self.y_scale_

    def _kernel(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        # In place: for the exact reference the matrix is n × n, several GB.
        k = a @ b.T
        k *= -2.0
        k += (a * a).sum(1)[:, None]
        k += (b * b).sum(1)[None, :]
        np.maximum(k, 0.0, out=k)
        k *= -0.5
        np.exp(k, out=k)
        k *= self.hyperparameters_["signal_variance"]
        return k

    def predict(self, X):  # noqa: N803
        check_is_fitted(self)
        X = validate_data(self, X, dtype=np.float64, reset=False)
        z = (X - self.x_mean_) / self.x_scale_ / self.length_scale_
        out = np.empty(len(z))
        for start in range(0, len(z), self._block):
            block = slice(start, start + self._block)
            out[block] = self._kernel(z[block], self.centres_) @ self.weights_
        return out * self.y_scale_ + self.y_mean_


class SparseGaussianProcess(_StandardisedRBF):
    """RBF Gaussian process (ARD) conditioned on every training sample via inducing points.

    Parameters
    ----------
    n_inducing : int
        Inducing points, drawn from the training inputs (all of them when fewer).
    hyper_subsample : int
        Samples on which the exact GP fits the hyperparameters (stratified on
        the target when it is discrete).
    ard : bool
        One length scale per input (True) or one for all.
    hyperparameters : mapping or None
        ``{"signal_variance", "length_scale", "noise_variance"}`` in the
        standardised units of a previous fit's ``hyperparameters_``: given, no
        optimisation happens (hyperparameters reused across folds).
    random_state : int
        Seeds the subsample and the inducing points.
    """

    def __init__(self, n_inducing: int = 500, hyper_subsample: int = 500, ard: bool = True,
                 hyperparameters: Mapping | None = None, random_state: int = 0) -> None:
        self.n_inducing = n_inducing
        self.hyper_subsample = hyper_subsample
        self.ard = ard
        self.hyperparameters = hyperparameters
        self.random_state = random_state

    def fit(self, X, y):  # noqa: N803 - scikit-learn's name
        X, y = validate_data(self, X, y, dtype=np.float64, y_numeric=True)
        if self.n_inducing < 1 or self.hyper_subsample < 2:
            raise ValueError("n_inducing must be ≥ 1 and hyper_subsample ≥ 2, got "
                             f"{self.n_inducing} and {self.hyper_subsample}")
        rng = check_random_state(self.random_state)
        xs, ys = self._standardise(X, y)

        self.convergence_warnings_: list[str] = []
        if self.hyperparameters is None:
            rows = subsample_rows(y, self.hyper_subsample, self.random_state)
            hyper, self.convergence_warnings_ = fit_rbf_hyperparameters(
                xs[rows], ys[rows], ard=self.ard, random_state=self.random_state)
        else:
            hyper = dict(self.hyperparameters)
        length = np.broadcast_to(np.asarray(hyper["length_scale"], dtype=float),
                                 (X.shape[1],)).copy()
        if np.any(length <= 0) or hyper["signal_variance"] <= 0 or hyper["noise_variance"] < 0:
            raise ValueError(f"hyperparameters out of range: {hyper}")
        self.hyperparameters_ = {"signal_variance": float(hyper["signal_variance"]),
                                 "length_scale": length.tolist(),
                                 "noise_variance": float(hyper["noise_variance"])}
        self.length_scale_ = length

        z = xs / length
        m = min(self.n_inducing, len(z))
        self.centres_ = z[np.sort(rng.choice(len(z), size=m, replace=False))]  # inducing points
        k_mm = self._kernel(self.centres_, self.centres_)
        chol_mm, self.jitter_ = stable_cholesky(k_mm)
        v = solve_triangular(chol_mm, self._kernel(self.centres_, z), lower=True,
                             check_finite=False)  # m × n
        noise = max(self.hyperparameters_["noise_variance"], 1e-6)
        a = v @ v.T + noise * np.eye(m)
        chol_a, _ = stable_cholesky(a)
        inner = cho_solve((chol_a, True), v @ ys, check_finite=False)
        self.weights_ = solve_triangular(chol_mm.T, inner, lower=False, check_finite=False)
        return self


class FixedKernelGaussianProcess(_StandardisedRBF):
    """The exact reference: an RBF GP conditioned on every training sample, no optimisation.

    Hyperparameters are fitted once on a subsample (as the ``paper`` model
    does) and then held fixed while the exact GP conditions on the whole
    fold: O(n³) time and O(n²) memory — the baseline the fast models are
    measured against, not a model to deploy.
    """

    _block = 2048  # each block is 2,048 × n: ~350 MB at a full fold

    def __init__(self, hyper_subsample: int = 2000, ard: bool = False,
                 random_state: int = 0) -> None:
        self.hyper_subsample = hyper_subsample
        self.ard = ard
        self.random_state = random_state

    def fit(self, X, y):  # noqa: N803
        X, y = validate_data(self, X, y, dtype=np.float64, y_numeric=True)
        xs, ys = self._standardise(X, y)
        rows = subsample_rows(y, self.hyper_subsample, self.random_state)
        self.hyperparameters_, self.convergence_warnings_ = fit_rbf_hyperparameters(
            xs[rows], ys[rows], ard=self.ard, random_state=self.random_state)
        self.length_scale_ = np.broadcast_to(
            np.asarray(self.hyperparameters_["length_scale"]), (X.shape[1],)).copy()
        self.centres_ = xs / self.length_scale_  # every training sample
        k = self._kernel(self.centres_, self.centres_)
        k[np.diag_indices_from(k)] += max(self.hyperparameters_["noise_variance"], 1e-6)
        chol, self.jitter_ = stable_cholesky(k)
        del k
        self.weights_ = cho_solve((chol, True), ys, check_finite=False)
        return self
