"""Two contacts scored as a set: match predicted to true contacts, then score.

Which contact is "first" is a labelling convention (docs/scenes.md: row-major order),
so a model that finds both contacts but names them in the other order has not
failed. Per sample, predicted contacts are assigned to true ones by
``scipy.optimize.linear_sum_assignment`` on a cost that counts a wrong node as
1 and breaks ties by distance (1e-3 per node pitch), so that the matching
first minimises the number of wrong contacts, then how far off they are.

Scores per sample: wrong contacts (0, 1 or 2 — a wrong contact costs exactly
one), pair right (both contacts right as a set), ghost (the predicted pair is
the truth's ghost: {(xa, yb), (xb, ya)} for {(xa, ya), (xb, yb)} — the pair a
row/column read-out cannot tell from the truth except by amplitude), and the
force error of each contact against the force predicted for the contact
matched to it — where the labels give each contact's force: a recording of their total
force only is scored on its positions alone.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment

from eskin.evaluation.metrics import regression, summarise
from eskin.kinds import DATASET_KINDS, TOTAL_FORCE_ONLY

TIE_BREAK = 1e-3
CONTACTS = (1, 2)


def match_contacts(true_nodes: np.ndarray, predicted_nodes: np.ndarray) -> np.ndarray:
    """For each sample, which predicted contact goes with each true contact.

    ``true_nodes`` and ``predicted_nodes`` have shape (n, k, 2): n samples, k
    contacts, (x, y). Returns (n, k) indices into the predicted contacts.
    """
    true_nodes = np.asarray(true_nodes, dtype=float)
    predicted_nodes = np.asarray(predicted_nodes, dtype=float)
    if true_nodes.shape != predicted_nodes.shape or true_nodes.ndim != 3:
        raise ValueError(f"expected two (n, k, 2) arrays, got {true_nodes.shape} and "
                         f"{predicted_nodes.shape}")
    difference = true_nodes[:, :, None, :] - predicted_nodes[:, None, :, :]
    wrong = np.any(difference != 0, axis=-1).astype(float)
    cost = wrong + TIE_BREAK * np.linalg.norm(difference, axis=-1)
    assignment = np.empty(true_nodes.shape[:2], dtype=np.int64)
    for i, sample_cost in enumerate(cost):
        rows, cols = linear_sum_assignment(sample_cost)
        assignment[i, rows] = cols
    return assignment


def _stack(frame: pd.DataFrame, pattern: str) -> np.ndarray:
    return np.stack([frame[[pattern.format(axis=a, i=i) for a in ("x", "y")]].to_numpy()
                     for i in CONTACTS], axis=1)


def pair_outcomes(frame: pd.DataFrame, forces: bool = True) -> pd.DataFrame:
    """Per sample: matched wrong contacts, ordered wrong contacts, and (``forces``)
    matched forces.

    ``frame`` holds ``x1_true … y2_true``, ``x1_pred … y2_pred`` and, with ``forces``,
    ``force1_true``, ``force2_true``, ``force1_pred``, ``force2_pred``.
    """
    true_nodes = _stack(frame, "{axis}{i}_true")
    predicted_nodes = _stack(frame, "{axis}{i}_pred")
    assignment = match_contacts(true_nodes, predicted_nodes)
    matched_nodes = np.take_along_axis(predicted_nodes, assignment[:, :, None], axis=1)
    wrong_matched = np.any(matched_nodes != true_nodes, axis=-1).sum(axis=1)
    wrong_ordered = np.any(predicted_nodes != true_nodes, axis=-1).sum(axis=1)
    ghost_nodes = np.stack([true_nodes[:, [0, 1], 0], true_nodes[:, [1, 0], 1]], axis=-1)
    has_ghost = np.all(true_nodes[:, 0] != true_nodes[:, 1], axis=-1)  # row and column differ
    ghost_assignment = match_contacts(ghost_nodes, predicted_nodes)
    ghost_matched = np.take_along_axis(predicted_nodes, ghost_assignment[:, :, None], axis=1)
    ghost = has_ghost & np.all(ghost_matched == ghost_nodes, axis=(1, 2))
    out = pd.DataFrame({
        "wrong_contacts": wrong_matched, "wrong_contacts_ordered": wrong_ordered,
        "swapped": (assignment[:, 0] == 1), "ghost": ghost, "has_ghost": has_ghost},
        index=frame.index)
    if not forces:
        return out
    forces_true = frame[[f"force{i}_true" for i in CONTACTS]].to_numpy(dtype=float)
    forces_pred = frame[[f"force{i}_pred" for i in CONTACTS]].to_numpy(dtype=float)
    matched_forces = np.take_along_axis(forces_pred, assignment, axis=1)
    return out.assign(
        **{f"force{i}_true": forces_true[:, k] for k, i in enumerate(CONTACTS)},
        **{f"force{i}_matched": matched_forces[:, k] for k, i in enumerate(CONTACTS)})


def pair_scores(outcomes: pd.DataFrame, forces: bool = True) -> dict[str, float]:
    """Pair accuracy (set and ordered), per-contact accuracy, the ghost share (of the pairs
    that have a ghost, the share predicted as it), and (``forces``) matched force error."""
    wrong = outcomes["wrong_contacts"].to_numpy()
    ordered = outcomes["wrong_contacts_ordered"].to_numpy()
    force = {}
    if forces:
        forces_true = outcomes[[f"force{i}_true" for i in CONTACTS]].to_numpy().ravel()
        forces_matched = outcomes[[f"force{i}_matched" for i in CONTACTS]].to_numpy().ravel()
        force = regression(forces_true, forces_matched)
    return {"pair_accuracy": float(np.mean(wrong == 0)),
            "pair_accuracy_ordered": float(np.mean(ordered == 0)),
            "contact_accuracy": float(1 - np.mean(wrong) / len(CONTACTS)),
            "contact_accuracy_ordered": float(1 - np.mean(ordered) / len(CONTACTS)),
            "swapped_share": float(outcomes["swapped"].mean()),
            "ghost_share": (float(outcomes["ghost"].sum() / outcomes["has_ghost"].sum())
                            if outcomes["has_ghost"].any() else float("nan")),
            **{f"force_{name}": value for name, value in force.items()}}


def score_pairs(localise: pd.DataFrame, force: pd.DataFrame | None
                ) -> dict[str, dict[str, float]]:
    """Per CV scheme, mean and std over folds of :func:`pair_scores`.

    The frames are the out-of-fold predictions of a two-force scene's localise and
    force tasks (one row per sample and scheme, keyed by trial and sample), scored on the
    samples where both contacts press; ``force``
    None: the scene has no per-contact forces, and its positions alone are scored.
    """
    joined = localise
    if force is not None:
        key = ["scheme", "trial", "sample"]
        forces = [f"force{i}_{what}" for i in CONTACTS for what in ("pred", "true")]
        joined = localise.merge(force[key + forces], on=key, validate="one_to_one")
        if len(joined) != len(localise):
            raise ValueError(f"the two-force predictions do not cover the same samples: "
                             f"{len(localise)} localised, {len(joined)} with both forces")
    # The pairs are the samples where every contact presses: those with fewer (a scene
    # recorded with contact_counts) have no pair to match; the detect task counts them.
    joined = joined[np.logical_and.reduce([joined[f"x{i}_true"].to_numpy() > 0
                                           for i in CONTACTS])]
    out = {}
    for scheme, rows in joined.groupby("scheme", sort=False):
        outcomes = pair_outcomes(rows, forces=force is not None)
        per_fold = [pair_scores(outcomes[rows["fold"].to_numpy() == f],
                                forces=force is not None)
                    for f in sorted(rows["fold"].unique())]
        out[str(scheme)] = summarise(per_fold)
    return out


@dataclass(frozen=True)
class PairsScored:
    """What :func:`score_scene_pairs` did: ``status`` is ``scored`` or ``skipped``
    (``reason``); ``document`` the scene's pairs scores as the report writes them (every
    scheme's, or the reason none); ``applies``: whether the scene has two contacts to
    pair at all (a one-contact scene's pairs have no file)."""

    scene: str
    status: str
    summary: str
    document: dict
    applies: bool
    reason: str = ""


def score_scene_pairs(scene: str, predictions: Mapping[str, pd.DataFrame],
                      localise: Mapping[str, Any] | None) -> PairsScored:
    """Score a two-force scene's contacts as sets (order-free), from its tasks' out-of-fold
    predictions (``predictions``, by task, as the report has read them); the scene's kind
    and dataset come from the localise task's scores document (``localise``; None: the
    scene has none). A recording of the contacts' total force only has its positions
    scored, and its per-contact force scores skipped with the reason (``skipped_scores``)."""
    document: dict[str, Any] = {"scene": scene, "task": "pairs"}
    localise = localise or {}

    def skip(reason: str, summary: str, *, applies: bool = True) -> PairsScored:
        return PairsScored(scene, "skipped", f"{scene}/pairs: skipped — {summary}",
                           {**document, "status": "skipped", "reason": reason}, applies,
                           reason)

    kind = DATASET_KINDS.get(localise.get("kind", ""))
    if kind is None or not kind.several:
        reason = f"a {localise.get('kind')} scene has one contact; pairs need two"
        return skip(reason, reason, applies=False)
    if kind.total_force:
        document["skipped_scores"] = {"force": TOTAL_FORCE_ONLY}
    frames = {}
    for task in ("localise",) if kind.total_force else ("localise", "force"):
        if task not in predictions:
            raise FileNotFoundError(f"{scene}/{task}: no predictions; run "
                                    f"`dvc repro train@{scene}`")
        frames[task] = predictions[task]
    if any(frame.empty for frame in frames.values()):
        skipped = [task for task, frame in frames.items() if frame.empty]
        return skip(f"no predictions from {', '.join(skipped)} (skipped)",
                    f"{', '.join(skipped)} skipped")
    scores = score_pairs(frames["localise"], frames.get("force"))
    document = {**document, "status": "scored", **scores}
    parts = [f"{scheme} pair {s['pair_accuracy']:.3f} (ordered {s['pair_accuracy_ordered']:.3f})"
             + (f", force R² {s['force_r2']:.3f}" if "force_r2" in s else "")
             for scheme, s in scores.items()]
    not_scored = "".join(f"; {what} scores skipped — {reason}"
                         for what, reason in document.get("skipped_scores", {}).items())
    return PairsScored(scene, "scored", f"{scene}/pairs: {'; '.join(parts)}{not_scored}",
                       document, True)
