"""The paper's figures, regenerated from out-of-fold predictions.

Each function takes predictions (one CV scheme) and returns a matplotlib
Figure; nothing here reads or writes files.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")  # files only: no display on a build machine
# SVG element ids are random (uuid4) unless salted: salted, the same figure is the same file.
matplotlib.rcParams["svg.hashsalt"] = "eskin"

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from sklearn.metrics import RocCurveDisplay, confusion_matrix  # noqa: E402

STYLE = {"font.size": 9, "axes.titlesize": 9, "axes.labelsize": 9, "legend.fontsize": 8,
         "xtick.labelsize": 8, "ytick.labelsize": 8, "figure.constrained_layout.use": True}
COLUMN_IN = 3.5   # one column of the paper, inches
PAGE_IN = 7.2     # both columns


def _ideal(ax, low: float, high: float, floor: float | None = None) -> None:
    """The ideal line, y = x, and equal axes around [low, high]; ``floor``: no axis below
    it (a force is never negative)."""
    pad = 0.05 * (high - low)
    start = low - pad if floor is None else max(floor, low - pad)
    ax.plot([start, high + pad], [start, high + pad], color="black", lw=1, ls="--",
            label="ideal", zorder=1)
    ax.set_xlim(start, high + pad)
    ax.set_ylim(start, high + pad)
    ax.set_aspect("equal")


def _level_summary(true: pd.Series, predicted: pd.Series) -> pd.DataFrame:
    return predicted.groupby(true.to_numpy()).agg(["mean", "std"]).fillna(0.0)


def stretch_parity(oof: pd.DataFrame) -> Figure:
    """Predicted against true λ: every prediction faint, mean ± std per level (paper Fig. 5).

    The spread within a level is far smaller than a marker, so the means are open circles
    over the points, the bars drawn on top with caps."""
    with plt.rc_context(STYLE):
        fig, ax = plt.subplots(figsize=(COLUMN_IN, COLUMN_IN))
        true, pred = oof["stretch_true"], oof["stretch_pred"].astype(float)
        _ideal(ax, min(true.min(), pred.min()), max(true.max(), pred.max()))
        ax.scatter(true, pred, s=2, alpha=0.05, color="tab:gray", rasterized=True, zorder=2)
        stats = _level_summary(true, pred)
        ax.errorbar(stats.index, stats["mean"], yerr=stats["std"], fmt="o", mfc="none",
                    color="tab:red", capsize=6, elinewidth=1.5, zorder=3, label="mean ± std")
        # the faint points' legend entry, drawn opaque so that it shows
        ax.scatter([], [], s=8, color="tab:gray", label="each prediction")
        ax.set_xlabel("true stretch λ")
        ax.set_ylabel("predicted stretch λ")
        ax.set_title("stretch")
        ax.legend(loc="upper left")
    return fig


MARKERS = ("o", "s", "^", "D", "v")


def force_parity(oof: pd.DataFrame, target: str = "force", by: str | None = "stretch",
                 ax=None, title: str | None = None) -> Figure:
    """Predicted against true force, mean ± std per level, a colour and marker per stretch
    (Fig. 6). Every point sits on its true force; open markers let overlaps show."""
    with plt.rc_context(STYLE):
        if ax is None:
            fig, ax = plt.subplots(figsize=(COLUMN_IN, COLUMN_IN))
        else:
            fig = ax.figure
        true = oof[f"{target}_true"]
        groups = [(None, oof)] if by is None else list(oof.groupby(by))
        spans = [_level_summary(rows[f"{target}_true"], rows[f"{target}_pred"].astype(float))
                 for _, rows in groups]
        _ideal(ax, min([0.0, true.min()] + [(s["mean"] - s["std"]).min() for s in spans]),
               max([true.max()] + [(s["mean"] + s["std"]).max() for s in spans]), floor=0.0)
        for k, ((level, _), stats) in enumerate(zip(groups, spans, strict=True)):
            label = "mean ± std" if level is None else f"λ = {level:.3g}"
            ax.errorbar(stats.index, stats["mean"], yerr=stats["std"],
                        fmt=MARKERS[k % len(MARKERS)], mfc="none", capsize=3 + 2 * k,
                        zorder=3, label=label)
        ax.set_xlabel("true force (N)")
        ax.set_ylabel("predicted force (N)")
        ax.set_title(title or "force")
        ax.legend(loc="upper left")
    return fig


def _confusion_panel(ax, true: np.ndarray, predicted: np.ndarray, name: str,
                     tick_names: dict | None = None):
    """Counts written in, colour the share of the true row (so that a rare class's row is
    as readable as a common one's); returns the image, for a colour bar."""
    labels = np.union1d(np.unique(true), np.unique(predicted))
    counts = confusion_matrix(true, predicted, labels=labels)
    rows = counts.sum(axis=1, keepdims=True)
    share = np.divide(counts, rows, out=np.zeros(counts.shape, dtype=float), where=rows > 0)
    image = ax.imshow(share, cmap="Blues", vmin=0, vmax=1)
    small = len(labels) > 6
    for (i, j), count in np.ndenumerate(counts):
        if count:
            text = f"{count:,}" if small else f"{count:,}\n{share[i, j]:.1%}"
            ax.text(j, i, text, ha="center", va="center", fontsize=6 if small else 8,
                    color="white" if share[i, j] > 0.6 else "black")
    ticks = np.arange(len(labels))
    names = [str((tick_names or {}).get(v, v)) for v in labels]
    ax.set_xticks(ticks, names)
    ax.set_yticks(ticks, names)
    ax.set_xlabel(f"predicted {name}")
    ax.set_ylabel(f"true {name}")
    return image


def confusion_grid(oof: pd.DataFrame, targets: list[str], names: list[str],
                   columns: int = 2, title: str | None = None) -> Figure:
    """Confusion matrices, counts written in, colour normalised per true row (Figs. 7, 8)."""
    with plt.rc_context(STYLE):
        rows = int(np.ceil(len(targets) / columns))
        fig, axes = plt.subplots(rows, columns, figsize=(PAGE_IN, PAGE_IN / columns * rows),
                                 squeeze=False)
        for ax, target, name in zip(axes.ravel(), targets, names, strict=False):
            image = _confusion_panel(ax, oof[f"{target}_true"].to_numpy(),
                                     oof[f"{target}_pred"].to_numpy(), name)
        for ax in axes.ravel()[len(targets):]:
            ax.set_visible(False)
        fig.colorbar(image, ax=axes.ravel().tolist(), shrink=0.8,
                     label="share of the true row")
        if title:
            fig.suptitle(title)
    return fig


def two_force_parity(oof: pd.DataFrame) -> Figure:
    """Force parity of contact 1 and contact 2 side by side (paper Fig. 9)."""
    with plt.rc_context(STYLE):
        fig, axes = plt.subplots(1, 2, figsize=(PAGE_IN, PAGE_IN / 2))
        force_parity(oof, "force1", by=None, ax=axes[0], title="force, contact 1")
        force_parity(oof, "force2", by=None, ax=axes[1], title="force, contact 2")
    return fig


def detection(oof: pd.DataFrame) -> Figure:
    """Contact detection: confusion matrix and ROC curve (scikit-learn's display)."""
    with plt.rc_context(STYLE):
        fig, (left, right) = plt.subplots(1, 2, figsize=(PAGE_IN, PAGE_IN / 2))
        true = oof["contact_true"].astype(bool).to_numpy()
        pred = oof["contact_pred"].astype(bool).to_numpy()
        image = _confusion_panel(left, true.astype(int), pred.astype(int), "class",
                                 {0: "no contact", 1: "contact"})
        fig.colorbar(image, ax=left, shrink=0.8, label="share of the true class")
        left.set_title("contact detection")
        if "contact_score" in oof and len(np.unique(true)) == 2:
            RocCurveDisplay.from_predictions(true, oof["contact_score"].astype(float).to_numpy(),
                                             ax=right, name="model",
                                             curve_kwargs={"color": "tab:red"},
                                             plot_chance_level=True)
            right.legend(loc="lower right")
        else:
            right.text(0.5, 0.5, "no scores from this model", ha="center", va="center")
            right.set_xlabel("false positive rate")
            right.set_ylabel("true positive rate")
        right.set_title("ROC")
        right.set_aspect("equal")
    return fig
