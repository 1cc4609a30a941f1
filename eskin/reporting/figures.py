"""The paper's figures, regenerated from out-of-fold predictions.

Each function takes predictions (one CV scheme) and returns a matplotlib
Figure; nothing here reads or writes files. What a figure shows (scene, task,
CV scheme, n, score) is written into it by :func:`identify`, from the report step.

scikit-learn's displays draw where they fit: ``ConfusionMatrixDisplay`` the
matrices' image, ticks and labels. Where one does not fit, the figure is drawn here
and the function says why: the parity plots (``PredictionErrorDisplay`` scatters
every prediction; Figs. 5, 6 and 9 show the mean ± std per true level and stretch,
set side by side), and the detection curve (``DetCurveDisplay``'s probit axes
stop at 0.1 %, above this detector's errors).
"""

from __future__ import annotations

import textwrap
from collections.abc import Callable

import matplotlib

matplotlib.use("Agg")  # files only: no display on a build machine
# SVG element ids are random (uuid4) unless salted: salted, the same figure is the same file.
matplotlib.rcParams["svg.hashsalt"] = "eskin"

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.text import Text  # noqa: E402
from sklearn.metrics import ConfusionMatrixDisplay, confusion_matrix, det_curve  # noqa: E402

# Text sizes, points. The page shows two page-wide figures side by side, 656 px each in a
# 1,400 px window: 1 pt is 1.27 px there, so TEXT_PT (9 pt) is 11.4 px (5.5 pt bar labels
# were 7 px). A confusion cell of many classes holds only CELL_TEXT_PT; the page shows
# such a figure wider (eskin/reporting/page.py Rendering.legible_width).
TEXT_PT = 9
STYLE = {"font.size": 10, "axes.titlesize": 10, "axes.labelsize": 10,
         "legend.fontsize": TEXT_PT, "xtick.labelsize": TEXT_PT, "ytick.labelsize": TEXT_PT,
         "figure.constrained_layout.use": True}
COLUMN_IN = 3.5   # one column of the paper, inches
PAGE_IN = 7.2     # both columns
HEADING_SIZE = TEXT_PT  # the heading identify() writes: scene, task, scheme, n, score

# The drawers a kind's figure may name (eskin/reporting/presentation.py Figure.draw), by
# name: a new figure registers its function with @drawer, and the report draws through it.
DRAWERS: dict[str, Callable[..., Figure]] = {}


def drawer(function: Callable[..., Figure]) -> Callable[..., Figure]:
    """Register ``function`` as a figure drawer, under its own name."""
    DRAWERS[function.__name__] = function
    return function


def identify(fig: Figure, heading: str) -> None:
    """Write what the figure shows (its heading: scene, task, CV scheme, n and score, a
    few lines) at its top, so that the figure says it wherever it is opened; a line
    wider than the figure is wrapped (constrained layout does not wrap a title)."""
    per_line = int(fig.get_figwidth() * 72 / (0.55 * HEADING_SIZE))
    lines = [wrapped for line in heading.splitlines()
             for wrapped in textwrap.wrap(line, per_line, break_on_hyphens=False)]
    with plt.rc_context(STYLE):
        fig.suptitle("\n".join(lines), fontsize=HEADING_SIZE, linespacing=1.4)


def smallest_text(fig: Figure) -> float:
    """The smallest font size (points) of the text the figure shows: what decides how
    wide the page must show it to be read."""
    return min(text.get_fontsize() for text in fig.findobj(Text)
               if text.get_visible() and text.get_text().strip()
               and (text.axes is None or text.axes.get_visible()))


def _ideal(ax, low: float, high: float, floor: float | None = None) -> None:
    """The ideal line, y = x, and equal axes around [low, high], padded on every side so
    that a point at either end is whole; ``floor``: the line and the ticks start there
    (a force is never negative), the axes a pad below it."""
    pad = 0.05 * (high - low) if high > low else 0.05
    start = low if floor is None else max(floor, low)
    ax.plot([start, high + pad], [start, high + pad], color="black", lw=1, ls="--",
            label="ideal", zorder=1)
    ax.set_xlim(low - pad, high + pad)
    ax.set_ylim(low - pad, high + pad)
    # equal scales: the same limits on both axes in a square box (set_aspect("equal")
    # shrinks the box after the layout, and with a heading above it the x label fell off)
    ax.set_box_aspect(1)
    if floor is not None:
        for axis, limits in ((ax.xaxis, ax.get_xlim()), (ax.yaxis, ax.get_ylim())):
            ticks = [t for t in axis.get_majorticklocs() if floor <= t <= limits[1]]
            axis.set_ticks(ticks)


# A target with more distinct values than this is continuous (a load cell's force in an
# imported recording): its levels are then LEVEL_BINS equal-width bins, each at its
# centre. (Level by value, a 4,000-row recording drew 4,000 bars and tick labels in 24 s.)
MAX_LEVELS = 12
LEVEL_BINS = 8


def binned(true: pd.Series) -> bool:
    """Whether ``true`` is continuous, so its levels are bins (:data:`MAX_LEVELS`)."""
    return true.nunique() > MAX_LEVELS


def _levels(true: pd.Series) -> np.ndarray:
    """Each row's level: its true value, or the centre of its bin where ``true`` is
    continuous."""
    values = true.to_numpy(dtype=float)
    if not binned(true):
        return values
    edges = np.linspace(values.min(), values.max(), LEVEL_BINS + 1)
    centres = (edges[:-1] + edges[1:]) / 2
    return centres[np.digitize(values, edges[1:-1])]


def _level_summary(true: pd.Series, predicted: pd.Series) -> pd.DataFrame:
    return predicted.groupby(_levels(true)).agg(["mean", "std"]).fillna(0.0)


@drawer
def stretch_parity(oof: pd.DataFrame) -> Figure:
    """Predicted against true λ: every prediction faint, mean ± std per level (paper Fig. 5).

    The spread within a level is far smaller than a marker, so the means are open circles
    over the points, the bars drawn on top with caps."""
    with plt.rc_context(STYLE):
        fig, ax = plt.subplots(figsize=(COLUMN_IN + 0.5, COLUMN_IN + 0.9))
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
        ax.set_title("predicted against true")
        ax.legend(loc="upper left")
    return fig


MARKERS = ("o", "s", "^", "D", "v")
# Two square panels side by side and, above them, the heading: tall enough that the
# squares are as wide as their half of the page (shorter, constrained layout squeezed
# the x label off the bottom).
PARITY_HEIGHT_IN = PAGE_IN / 2 + 1.1
# Where the levels are few, the x ticks are the levels themselves.
MAX_LEVEL_TICKS = 8


def _series(oof: pd.DataFrame, target: str, by: str | None
            ) -> list[tuple[str, pd.DataFrame]]:
    """(legend label, mean and std per true level) of each series: one per ``by`` value."""
    groups = [(None, oof)] if by is None else list(oof.groupby(by))
    return [("mean ± std" if level is None else f"λ = {level:.3g}",
             _level_summary(rows[f"{target}_true"], rows[f"{target}_pred"].astype(float)))
            for level, rows in groups]


def _parity_panel(ax, oof: pd.DataFrame, target: str, by: str | None, title: str) -> list:
    """Predicted against true force, mean ± std per level, a colour and marker per series.

    Series at the same true force are set side by side about it (dodged), so that each
    one's bar shows; the x ticks are the true levels."""
    true = oof[f"{target}_true"]
    series = _series(oof, target, by)
    levels = np.sort(true.unique())
    low = min([0.0, true.min()] + [(s["mean"] - s["std"]).min() for _, s in series])
    high = max([true.max()] + [(s["mean"] + s["std"]).max() for _, s in series])
    _ideal(ax, low, high, floor=0.0)
    step = 0.035 * (high - low) if len(series) > 1 else 0.0
    for k, (label, stats) in enumerate(series):
        offset = (k - (len(series) - 1) / 2) * step
        ax.errorbar(stats.index + offset, stats["mean"], yerr=stats["std"],
                    fmt=MARKERS[k % len(MARKERS)], mfc="none", ms=5, capsize=3, zorder=3,
                    label=label)
    if len(levels) <= MAX_LEVEL_TICKS:
        ax.set_xticks(levels, [f"{v:.3g}" for v in levels])
    ax.set_xlabel("true force (N)")
    ax.set_ylabel("predicted force (N)")
    ax.set_title(title)
    ax.legend(loc="upper left")
    return series


def _spread_panel(ax, series: list, in_bins: bool = False) -> None:
    """The std of the prediction per true level, in newtons: a bar per series and level,
    its value written on it (what the paper's Fig. 6 reports); ``in_bins``: the levels
    are bins of a continuous force."""
    levels = sorted(set().union(*(stats.index for _, stats in series)))
    width = 0.8 / len(series)
    for k, (label, stats) in enumerate(series):
        positions = [levels.index(v) + (k - (len(series) - 1) / 2) * width
                     for v in stats.index]
        bars = ax.bar(positions, stats["std"], width=width * 0.95, label=label,
                      color=f"C{k}", alpha=0.8)
        # upright: at TEXT_PT, "0.27" is wider than a bar of three per level
        ax.bar_label(bars, fmt="%.2f", fontsize=TEXT_PT, padding=2, rotation=90)
    ax.set_xticks(range(len(levels)), [f"{v:.3g}" for v in levels])
    ax.set_xlabel(f"true force (N){', centre of its bin' if in_bins else ''}")
    ax.set_ylabel("std of the predicted force (N)")
    ax.set_title(f"spread per {'bin' if in_bins else 'level'}")
    ax.margins(y=0.2)  # room above the tallest bar for its upright label
    ax.legend(loc="upper left")


@drawer
def force_parity(oof: pd.DataFrame, target: str = "force", by: str | None = "stretch"
                 ) -> Figure:
    """Force (paper Fig. 6): left, predicted against true force, mean ± std per level, a
    colour and marker per stretch, set side by side about their level; right, the std
    per level and stretch in newtons, which is what Fig. 6 is about."""
    with plt.rc_context(STYLE):
        fig, (parity, spread) = plt.subplots(1, 2, figsize=(PAGE_IN, PARITY_HEIGHT_IN))
        series = _parity_panel(parity, oof, target, by, "predicted against true")
        _spread_panel(spread, series, binned(oof[f"{target}_true"]))
    return fig


def _annotate_spread(ax, stats: pd.DataFrame) -> None:
    """The std of each level, in newtons, written beside its bar (left of it near the
    right edge), on white so that the ideal line does not cross it."""
    right = ax.get_xlim()[1]
    for level, row in stats.iterrows():
        near_edge = level > 0.75 * right
        ax.annotate(f"std {row['std']:.2f} N", (level, row["mean"]),
                    xytext=(-8 if near_edge else 8, 0), textcoords="offset points",
                    ha="right" if near_edge else "left", va="center", fontsize=TEXT_PT,
                    color="0.2", bbox={"fc": "white", "ec": "none", "pad": 0.5},
                    in_layout=False)


@drawer
def two_force_parity(oof: pd.DataFrame) -> Figure:
    """Force parity of contact 1 and contact 2 side by side (paper Fig. 9), the std of
    each level written beside it (one series a panel: nothing to dodge)."""
    with plt.rc_context(STYLE):
        fig, axes = plt.subplots(1, 2, figsize=(PAGE_IN, PARITY_HEIGHT_IN))
        for ax, contact in zip(axes, (1, 2), strict=True):
            series = _parity_panel(ax, oof, f"force{contact}", None, f"contact {contact}")
            _annotate_spread(ax, series[0][1])
    return fig


@drawer
def total_force_parity(oof: pd.DataFrame) -> Figure:
    """The total force of two contacts, predicted against true: every prediction and the
    ideal line. A recording of one force sensor under both contacts is continuous, so
    there are no levels to take a mean ± std at (Figs. 6 and 9 have them)."""
    with plt.rc_context(STYLE):
        fig, ax = plt.subplots(figsize=(COLUMN_IN + 0.5, COLUMN_IN + 0.9))
        true, pred = oof["force_true"], oof["force_pred"].astype(float)
        _ideal(ax, min(0.0, pred.min()), max(true.max(), pred.max()), floor=0.0)
        ax.scatter(true, pred, s=3, alpha=0.3, color="tab:blue", rasterized=True, zorder=2,
                   label="each prediction")
        ax.set_xlabel("true total force (N)")
        ax.set_ylabel("predicted total force (N)")
        ax.set_title("predicted against true")
        ax.legend(loc="upper left")
    return fig


def _share(share: float) -> str:
    """A share as a percentage that tells a rare error from none: 0.011%, 99.989%."""
    if share in (0.0, 1.0):
        return f"{share:.0%}"
    if share < 0.001:
        return f"{share * 100:.2g}%"
    if share > 0.999:
        return f"{share * 100:.3f}%"
    return f"{share:.1%}"


# The most classes whose confusion cells still fit their count and share (16 × 12 skins'
# 16 x terminals do, 32 do not).
WRITTEN_LABELS = 16
# Beyond SMALL_CELLS classes, a cell's count and share fit at CELL_TEXT_PT only (10
# classes in half the page's width: a cell is 18.7 pt wide, "0.056%" at 5 pt 18.0 pt).
SMALL_CELLS = 6
CELL_TEXT_PT = 5


def _confusion_panel(ax, true: np.ndarray, predicted: np.ndarray, name: str,
                     tick_names: dict | None = None):
    """One confusion matrix: colour the share of the samples with the same true value
    (so that a rare class's row reads as well as a common one's), every non-zero cell's
    count and share written in, up to :data:`WRITTEN_LABELS` classes (beyond, a cell is
    too small to write in: the colour tells). Returns the image, for a colour bar.

    ConfusionMatrixDisplay draws the image, ticks and labels; it writes the values it
    colours, and these cells show a count beside the share they are coloured by, so the
    text is written here (include_values=False)."""
    labels = np.union1d(np.unique(true), np.unique(predicted))
    counts = confusion_matrix(true, predicted, labels=labels)
    rows = counts.sum(axis=1, keepdims=True)
    share = np.divide(counts, rows, out=np.zeros(counts.shape, dtype=float), where=rows > 0)
    names = [str((tick_names or {}).get(v, v)) for v in labels]
    display = ConfusionMatrixDisplay(share, display_labels=names)
    display.plot(ax=ax, cmap="Blues", colorbar=False, include_values=False,
                 im_kw={"vmin": 0, "vmax": 1})
    small = len(labels) > SMALL_CELLS
    if small:  # 16 classes' two-digit tick labels run together at TEXT_PT
        ax.tick_params(labelsize=TEXT_PT - 1)
    written = counts if len(labels) <= WRITTEN_LABELS else np.zeros_like(counts)
    for (i, j), count in np.ndenumerate(written):
        if count:
            ax.text(j, i, f"{count:,}\n{_share(share[i, j])}", ha="center", va="center",
                    fontsize=CELL_TEXT_PT if small else TEXT_PT, linespacing=1.1,
                    color="white" if share[i, j] > 0.6 else "black")
    ax.set_xlabel(f"predicted {name}")
    ax.set_ylabel(f"true {name}")
    return display.im_


def share_label(name: str) -> str:
    """The colour bar's label: the share of which samples a colour is."""
    return f"share of samples with this true {name.split()[-1]}"


@drawer
def confusion_grid(oof: pd.DataFrame, targets: list[str], names: list[str],
                   columns: int = 2, title: str | None = None) -> Figure:
    """Confusion matrices, counts and shares written in, colour the share of the samples
    with the same true terminal (Figs. 7, 8)."""
    with plt.rc_context(STYLE):
        rows = int(np.ceil(len(targets) / columns))
        fig, axes = plt.subplots(rows, columns,
                                 figsize=(PAGE_IN, PAGE_IN / columns * rows + 0.5),
                                 squeeze=False)
        for ax, target, name in zip(axes.ravel(), targets, names, strict=False):
            image = _confusion_panel(ax, oof[f"{target}_true"].to_numpy(),
                                     oof[f"{target}_pred"].to_numpy(), name)
            ax.set_title(name.split()[0])
        for ax in axes.ravel()[len(targets):]:
            ax.set_visible(False)
        fig.colorbar(image, ax=axes.ravel().tolist(), shrink=0.8,
                     label=share_label(names[0]))
    return fig


def _percent(rate: float) -> str:
    return f"{rate * 100:.4g}%"


def _det_panel(ax, true: np.ndarray, pred: np.ndarray, score: np.ndarray | None) -> None:
    """Missed contacts against false contacts (a DET curve), both on log axes, and the
    model's operating point, its counts written beside it.

    The curve is scikit-learn's ``det_curve``, drawn here rather than by DetCurveDisplay:
    the display's probit axes stop at 0.1 % and squeeze the decades below 1 % into a
    corner, and this detector's errors are a few in ten thousand; log axes give every
    decade the same room. A rate of 0 has no logarithm: it is drawn on the axis's edge
    (the counts say it is 0)."""
    negatives, positives = int((~true).sum()), int(true.sum())
    false_contacts, missed = int((pred & ~true).sum()), int((~pred & true).sum())
    floor = 10.0 ** np.floor(np.log10(0.5 / max(negatives, positives, 1)))
    if score is not None and negatives and positives:
        fpr, fnr, _ = det_curve(true, score, pos_label=True)
        ax.step(np.maximum(fpr, floor), np.maximum(fnr, floor), where="post",
                color="tab:red", label="model, every threshold")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlim(floor, 1.0)
    ax.set_ylim(floor, 1.0)
    ticks = 10.0 ** np.arange(np.log10(floor), 0.5)
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_ticks(ticks, [_percent(t) for t in ticks], fontsize=TEXT_PT)
        axis.set_ticks([], minor=True)
    ax.set_aspect("equal")
    ax.grid(True, color="0.9", lw=0.5)
    point = [max(rate, floor) for rate in (false_contacts / max(negatives, 1),
                                           missed / max(positives, 1))]
    ax.plot(*point, "o", color="black", ms=6, mfc="none", zorder=4,
            label=f"its decisions: {false_contacts:,} false of {negatives:,},\n"
                  f"{missed:,} missed of {positives:,}")
    # two lines each: at TEXT_PT, one was wider than the panel, and off the figure
    ax.set_xlabel("false contacts\n(of no-contact samples)")
    ax.set_ylabel("missed contacts\n(of contact samples)")
    ax.set_title("DET curve, log axes")
    # under the figure: at TEXT_PT the legend is wider than the panel, and on it, it hid
    # the curve and a tick label
    ax.figure.legend(*ax.get_legend_handles_labels(), loc="outside lower right",
                     fontsize=TEXT_PT)
    if score is None:
        ax.text(0.5, 0.6, "no scores from this model:\nits decisions only",
                transform=ax.transAxes, ha="center", va="center", fontsize=TEXT_PT)


# Tall enough for the DET legend under the figure and a DET panel whose six decades'
# tick labels fit side by side at TEXT_PT.
DETECTION_HEIGHT_IN = PAGE_IN / 2 + 0.9


@drawer
def detection(oof: pd.DataFrame) -> Figure:
    """Contact detection: confusion counts (ConfusionMatrixDisplay) and the DET curve on
    log axes with the model's operating point. At this accuracy the ROC curve is a
    corner (AUC 1.00); the DET curve spreads the rare errors over decades."""
    with plt.rc_context(STYLE):
        fig, (left, right) = plt.subplots(1, 2, figsize=(PAGE_IN, DETECTION_HEIGHT_IN),
                                          width_ratios=(1, 1.5))
        fig.get_layout_engine().set(wspace=0.06)  # room between the colour bar and the DET
        true = oof["contact_true"].astype(bool).to_numpy()
        pred = oof["contact_pred"].astype(bool).to_numpy()
        image = _confusion_panel(left, true.astype(int), pred.astype(int), "class",
                                 {0: "no contact", 1: "contact"})
        fig.colorbar(image, ax=left, shrink=0.8, label=share_label("class"))
        left.set_title("confusion counts")
        score = (oof["contact_score"].astype(float).to_numpy()
                 if "contact_score" in oof and len(np.unique(true)) == 2 else None)
        _det_panel(right, true, pred, score)
    return fig
