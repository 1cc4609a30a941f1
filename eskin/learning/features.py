"""Features from the skin's channels: the paper's raw readings, or a fitted transform.

``featurize.method`` chooses:

* ``raw`` — the channel readings as they are (the paper);
* ``standardise`` — each channel to zero mean and unit variance;
* ``baseline`` — each channel minus its mean over the no-contact, unstretched
  samples: the change a contact or a stretch makes, which removes the
  terminals' own baselines. On a real bench that baseline is the reading
  taken before the first press, so fitting it on those samples is
  calibration, not leakage.

Each is a scikit-learn transformer; the fitted one is saved beside the
features so that live inference applies exactly the same transform. This module reads
and writes nothing: the featurize step (:mod:`eskin.steps.featurize`) does.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.preprocessing import FunctionTransformer, StandardScaler
from sklearn.utils.validation import check_is_fitted, validate_data

from eskin.data.schema import contact_mask
from eskin.skin import AnySkin

METHODS = ("raw", "standardise", "baseline")


class BaselineDelta(TransformerMixin, BaseEstimator):
    """Subtract the per-channel mean of the samples it was fitted on.

    Fit it on baseline samples (no contact, unstretched); transform any.

    Examples
    --------
    >>> import numpy as np
    >>> BaselineDelta().fit(np.array([[1.0, 2.0], [3.0, 4.0]])).transform([[2.0, 3.0]])
    array([[0., 0.]])
    """

    def fit(self, X, y=None):  # noqa: N803 - scikit-learn's name
        X = validate_data(self, X, dtype=np.float64)
        self.baseline_ = X.mean(axis=0)
        return self

    def transform(self, X):  # noqa: N803
        check_is_fitted(self)
        X = validate_data(self, X, dtype=np.float64, reset=False)
        return X - self.baseline_


def make_featurizer(method: str) -> TransformerMixin:
    if method == "raw":
        return FunctionTransformer(feature_names_out="one-to-one")
    if method == "standardise":
        return StandardScaler()
    if method == "baseline":
        return BaselineDelta()
    raise ValueError(f"featurize.method must be one of {METHODS}, got {method!r}")


def baseline_rows(frame: pd.DataFrame) -> np.ndarray:
    """No-contact samples at the lowest stretch recorded."""
    rest = frame["stretch"] == frame["stretch"].min()
    return (rest.to_numpy() & ~contact_mask(frame))


def fit_featurizer(method: str, frame: pd.DataFrame, kind: str,
                   skin: AnySkin) -> TransformerMixin:
    """The transform of ``method`` fitted on ``frame``'s channels of ``skin`` (baseline: on
    its rest samples)."""
    featurizer = make_featurizer(method)
    channels = frame[skin.channels]
    if method == "baseline":
        rows = baseline_rows(frame)
        if not rows.any():
            raise ValueError(
                "featurize.method 'baseline' needs no-contact samples at the lowest stretch, "
                f"and this {kind} dataset has none; use 'raw' or 'standardise'")
        channels = channels[rows]
    return featurizer.fit(channels)


def featurize(frame: pd.DataFrame, featurizer: TransformerMixin, skin: AnySkin) -> pd.DataFrame:
    """``frame`` with its channels of ``skin`` replaced by features (same names), labels
    kept."""
    features = np.asarray(featurizer.transform(frame[skin.channels]), dtype=np.float64)
    out = frame.copy()
    out[skin.channels] = features
    return out
