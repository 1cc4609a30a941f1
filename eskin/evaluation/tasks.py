"""What each scene can learn: the tasks, their targets, rows, and preconditions.

Single force (the paper's section III-D):

* ``stretch`` — λ from every sample (needs two or more stretch levels);
* ``force`` — newtons from every sample, the physical force: 0 wherever no
  indenter presses (node 0 and every 0 N sample), since the recorded force of
  a node-0 sample names a weight that was not on the skin;
* ``detect`` — contact (force > 0 and node > 0) against none, every sample;
* ``localise`` — x and y of the pressed node, contact samples only (the
  paper's localisation "assumes that there is pressure on the sensor"); on a
  skin that places its positions in mm, also each contact's position error in mm.

Two forces (section III-E): ``force`` (force1 and force2, one model each), every
sample, and ``localise`` (x1, y1, x2, y2), samples with a contact; ``stretch`` where the
scene has two or more levels. ``detect`` learns how many contacts press (0, 1 or 2), and
needs samples with fewer than two: the paper's plan presses both on every sample, and
the task is skipped, with that reason in its metrics file; a scene recorded with
``contact_counts: [0, 1, 2]`` has them (an absent contact is node 0, after the pressed
ones). A recording of two contacts that gives their total force only (the kind's
total-force variant) has one force target, ``force``, the total; its positions are
learnt as any two contacts'.

Every kind has the same task names (:data:`TASK_NAMES`), so the stage graph is
scenes × tasks, and a task a scene's data cannot support is skipped by the data,
not by a list of which scene runs what.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from eskin.catalog import HEADLINE_METRIC
from eskin.data.schema import contact_count, contact_mask
from eskin.kinds import DATASET_KINDS, Kind, get_kind


def _all_rows(frame: pd.DataFrame) -> np.ndarray:
    return np.ones(len(frame), dtype=bool)


def _physical_force(force: str, nodes: list[str]) -> Callable[[pd.DataFrame], np.ndarray]:
    """The force column ``force`` where it presses a node (one of the ``nodes`` columns of
    the contacts it weighs is not 0), else 0."""
    def target(frame: pd.DataFrame) -> np.ndarray:
        values = frame[force].to_numpy(dtype=float)
        at_node = np.logical_or.reduce([frame[x].to_numpy() > 0 for x in nodes])
        return np.where((values > 0) & at_node, values, 0.0)
    return target


def _column(name: str) -> Callable[[pd.DataFrame], np.ndarray]:
    return lambda frame: frame[name].to_numpy()


@dataclass(frozen=True)
class Task:
    """A learning task: a model role, a scorer, and a target per output."""

    name: str
    role: str                     # entry of eskin.learning.estimators.REGISTRY
    scorer: str                   # entry of eskin.evaluation.metrics.SCORERS
    targets: dict[str, Callable[[pd.DataFrame], np.ndarray]]
    rows: Callable[[pd.DataFrame], np.ndarray] = _all_rows
    row_note: str = "every sample"
    # Each contact's position (``position``, or ``position1``…) → its (x, y) targets:
    # scored as a distance in mm where the skin places its nodes in mm.
    positions: dict[str, tuple[str, str]] = field(default_factory=dict)

    def target_values(self, frame: pd.DataFrame) -> dict[str, np.ndarray]:
        return {name: get(frame) for name, get in self.targets.items()}

    @property
    def headline_metric(self) -> str:
        return HEADLINE_METRIC[self.scorer]

    def headline(self, scores: Mapping[str, Mapping[str, float]]) -> float:
        """The task's one score (mean over its targets of the headline metric)."""
        return float(np.mean([scores[target][self.headline_metric] for target in self.targets]))

    def unsupported(self, frame: pd.DataFrame) -> str | None:
        """Why this scene cannot train the task, or None when it can."""
        if not self.targets:
            return f"this kind of scene has no {self.name} labels"
        rows = self.rows(frame)
        if not rows.any():
            return f"no rows for {self.name} ({self.row_note})"
        if self.name == "stretch" and frame["stretch"].nunique() < 2:
            return ("stretch regression needs two or more stretch levels; this scene has one "
                    f"(λ = {frame['stretch'].iloc[0]:g})")
        for name, values in self.target_values(frame[rows]).items():
            if len(np.unique(values)) < 2:
                if self.name == "detect" and name == "contact":
                    has = "a contact" if bool(np.unique(values)[0]) else "no contact"
                    return ("detect needs contact and no-contact samples; every sample of "
                            f"this scene has {has}")
                if self.name == "detect":
                    return ("detect counts the contacts and needs samples with different "
                            f"counts; every sample of this scene has {np.unique(values)[0]} "
                            "(record some with fewer: scenes.<scene>.contact_counts)")
                return (f"{self.name} needs two or more distinct values of {name}; this scene "
                        f"has only {np.unique(values)[0].item()!r}")
        return None


def _tasks(kind: Kind) -> dict[str, Task]:
    """The tasks of a kind of scene, in TASK_NAMES order."""
    # The detector decides first: localisation learns from contact samples only (with two
    # contacts on the paper's plan, that is every sample).
    counts = {"contact": contact_mask, "contacts": contact_count}
    detected = {kind.detect_target: counts[kind.detect_target]} if kind.detect_target else {}
    return {
        "stretch": Task("stretch", "stretch", "regression", {"stretch": _column("stretch")}),
        "force": Task("force", "force", "regression",
                      {force: _physical_force(force, nodes)
                       for force, nodes in kind.weighed_contacts.items()}),
        "detect": Task("detect", "detect", kind.detect_scorer, detected),
        "localise": Task("localise", "localise", "localisation",
                         {name: _column(name) for name in kind.node_columns}, contact_mask,
                         "contact samples", positions=kind.positions),
    }


TASKS: dict[str, dict[str, Task]] = {name: _tasks(kind) for name, kind in DATASET_KINDS.items()}


def get_task(kind: str, name: str) -> Task:
    get_kind(kind)  # an unknown kind: the one error that lists the kinds
    if name not in TASKS[kind]:
        raise ValueError(f"a {kind} scene has no task {name!r}; known: {sorted(TASKS[kind])}")
    return TASKS[kind][name]
