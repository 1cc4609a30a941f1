"""Scores of out-of-fold predictions: regression, detection, localisation."""

from __future__ import annotations

import warnings

import numpy as np
from sklearn.metrics import (
    accuracy_score,
    balanced_accuracy_score,
    confusion_matrix,
    f1_score,
    mean_absolute_error,
    mean_squared_error,
    r2_score,
    roc_auc_score,
)


def regression(y_true: np.ndarray, y_pred: np.ndarray, score=None) -> dict[str, float]:
    mse = mean_squared_error(y_true, y_pred)
    return {"r2": float(r2_score(y_true, y_pred)) if np.ptp(y_true) > 0 else float("nan"),
            "mse": float(mse), "rmse": float(np.sqrt(mse)),
            "mae": float(mean_absolute_error(y_true, y_pred))}


def detection(y_true: np.ndarray, y_pred: np.ndarray,
              score: np.ndarray | None = None) -> dict[str, float]:
    """Accuracy, balanced accuracy, F1; ROC AUC when the model gives a score."""
    y_true = np.asarray(y_true, dtype=bool)
    y_pred = np.asarray(y_pred, dtype=bool)
    out = {"accuracy": float(accuracy_score(y_true, y_pred)),
           "balanced_accuracy": float(balanced_accuracy_score(y_true, y_pred)),
           "f1": float(f1_score(y_true, y_pred, zero_division=0.0))}
    if score is not None:
        both = len(np.unique(y_true)) == 2
        out["roc_auc"] = float(roc_auc_score(y_true, score)) if both else float("nan")
    return out


def localisation(y_true: np.ndarray, y_pred: np.ndarray, score=None) -> dict[str, float]:
    """Accuracy, balanced accuracy, macro F1 and the share within one node of the truth."""
    y_true = np.asarray(y_true)
    y_pred = np.asarray(y_pred)
    return {**_class_scores(y_true, y_pred),
            "within_one": float(np.mean(np.abs(y_true.astype(float) - y_pred) <= 1))}


def _class_scores(y_true: np.ndarray, y_pred: np.ndarray) -> dict[str, float]:
    """Accuracy, balanced accuracy and macro F1 of class labels (nodes, or counts)."""
    with warnings.catch_warnings():
        # A conditions fold may hold no sample of a class the model still predicts: the
        # score is then over the classes present, which is what a fold can measure.
        warnings.filterwarnings("ignore", message="y_pred contains classes not in y_true")
        balanced = balanced_accuracy_score(y_true, y_pred)
    return {"accuracy": float(accuracy_score(y_true, y_pred)),
            "balanced_accuracy": float(balanced),
            "f1_macro": float(f1_score(y_true, y_pred, average="macro", zero_division=0.0))}


def position_error_mm(x_true: np.ndarray, y_true: np.ndarray, x_pred: np.ndarray,
                      y_pred: np.ndarray, x_mm, y_mm) -> dict[str, float]:
    """The mean Euclidean distance in mm between true and predicted positions, node
    numbers (1-based) placed by the skin's ``x_mm``/``y_mm``. Rows where either side
    places no contact (node 0: an absent contact of a count below the kind's; the detect
    task scores the count) are left out; NaN when none is left."""
    x_mm, y_mm = np.asarray(x_mm, dtype=float), np.asarray(y_mm, dtype=float)
    nodes = [np.asarray(v, dtype=np.int64) for v in (x_true, y_true, x_pred, y_pred)]
    if any((v < 0).any() for v in nodes):
        raise ValueError("a position is a node (1 and above) or 0 (no contact)")
    placed = np.logical_and.reduce([v > 0 for v in nodes])
    if not placed.any():
        return {"error_mm": float("nan")}
    x_true, y_true, x_pred, y_pred = (v[placed] for v in nodes)
    distance = np.hypot(x_mm[x_true - 1] - x_mm[x_pred - 1], y_mm[y_true - 1] - y_mm[y_pred - 1])
    return {"error_mm": float(distance.mean())}


def counting(y_true: np.ndarray, y_pred: np.ndarray, score=None) -> dict[str, float]:
    """How many contacts press: accuracy, balanced accuracy and macro F1 over the counts,
    and the accuracy of "any contact" (a count above 0), the single-contact detector's."""
    y_true = np.asarray(y_true, dtype=np.int64)
    y_pred = np.asarray(y_pred, dtype=np.int64)
    return {**_class_scores(y_true, y_pred),
            "contact_accuracy": float(accuracy_score(y_true > 0, y_pred > 0))}


SCORERS = {"regression": regression, "detection": detection, "localisation": localisation,
           "counting": counting}


def confusion(y_true: np.ndarray, y_pred: np.ndarray) -> dict[str, list]:
    """Counts with rows = truth, columns = prediction, over the union of labels."""
    labels = np.union1d(np.unique(y_true), np.unique(y_pred))
    matrix = confusion_matrix(y_true, y_pred, labels=labels)
    return {"labels": labels.tolist(), "counts": matrix.tolist()}


def summarise(per_fold: list[dict[str, float]]) -> dict[str, float]:
    """Mean and standard deviation over folds of each score (``r2``, ``r2_std``)."""
    out: dict[str, float] = {}
    for name in per_fold[0]:
        values = np.array([fold[name] for fold in per_fold], dtype=float)
        finite = values[np.isfinite(values)]
        out[name] = float(finite.mean()) if finite.size else float("nan")
        out[f"{name}_std"] = float(finite.std()) if finite.size else float("nan")
    return out
