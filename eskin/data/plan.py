"""Scenes as plans: the ordered list of conditions an experiment records.

A condition is what determines a trial: the stretch and the contacts (node
and force of each indenter). A plan records each condition ``repeats`` times
(``scenes.<scene>.repeats``, default 1: the paper's protocol), the whole plan
once, then again: each repetition is a trial of its own, with the weights
placed anew. A trial's key adds the device (id and firmware) and, from the
second repetition on, the repetition's number, so a trial recorded once on a
device is never recorded again on it — when a plan grows (more conditions or
more repeats), only the new trials are acquired — while another device, or a
simulator with other settings, starts afresh.

Label conventions (docs/scenes.md):

* single force — node 0 means "no indenter on the skin". As in the paper's
  data, node 0 is recorded at every force level and every node at 0 N; a
  sample is a contact only when force > 0 and node > 0.
* two forces — contact 1 is the contact whose node comes first in row-major
  order (lower x, then lower y); contact 2 is the other. A condition where fewer
  press (``contact_counts``) names its absent contacts last, at node 0: one
  contact is contact 1.
"""

from __future__ import annotations

import hashlib
import itertools
import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from eskin.config.scenes import scene_skin
from eskin.kinds import ONE_CONTACT, TWO_CONTACTS
from eskin.skin import PAPER_SKIN, AnySkin

if TYPE_CHECKING:
    from eskin.config.scenes import AcquiredScene


@dataclass(frozen=True, order=True)
class Contact:
    """An indenter on node (x, y) with ``force`` newtons; x = y = 0 is no indenter."""

    x: int
    y: int
    force: float

    @property
    def touches(self) -> bool:
        return self.x > 0 and self.force > 0


@dataclass(frozen=True)
class Condition:
    """One trial of a plan: a condition (stretch and contacts) and its repetition,
    0 for the first."""

    stretch: float
    contacts: tuple[Contact, ...]
    repeat: int = 0

    def as_dict(self) -> dict[str, object]:
        # The first repetition is written as before repeats existed: its raw-log records
        # and its key are those of a plan of one repetition.
        return {"stretch": self.stretch,
                "contacts": [[c.x, c.y, c.force] for c in self.contacts],
                **({"repeat": self.repeat} if self.repeat else {})}

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> Condition:
        contacts = tuple(Contact(int(x), int(y), float(f)) for x, y, f in data["contacts"])
        return cls(float(data["stretch"]), contacts, int(data.get("repeat", 0)))

    def key(self, device_id: str, firmware: str) -> str:
        """Stable id of this trial on this device (16 hex digits)."""
        canonical = {"device": device_id, "firmware": firmware,
                     "stretch": round(self.stretch, 6),
                     "contacts": [[c.x, c.y, round(c.force, 6)] for c in self.contacts],
                     **({"repeat": self.repeat} if self.repeat else {})}
        blob = json.dumps(canonical, sort_keys=True).encode()
        return hashlib.sha256(blob).hexdigest()[:16]

    def describe(self) -> str:
        touching = [c for c in self.contacts if c.touches]
        where = " + ".join(f"{c.force:g} N on ({c.x},{c.y})" for c in touching) or "no contact"
        again = f", repetition {self.repeat + 1}" if self.repeat else ""
        return f"λ={self.stretch:g}, {where}{again}"


@dataclass(frozen=True)
class ScenePlan:
    """A scene's trials in the order they are recorded: every condition once, then every
    condition again, ``repeats`` times in all."""

    name: str
    kind: str
    conditions: tuple[Condition, ...]
    samples: int
    skin: AnySkin = PAPER_SKIN
    repeats: int = 1

    @property
    def n_samples(self) -> int:
        return len(self.conditions) * self.samples

    def as_dict(self) -> dict[str, object]:
        # "conditions" counts trials, as it did when every condition was one trial; a plan
        # of one repetition is described as before repeats existed (datasets keep bytes).
        return {"name": self.name, "kind": self.kind, "samples": self.samples,
                "conditions": len(self.conditions),
                **({"repeats": self.repeats} if self.repeats > 1 else {})}


def _repeated(conditions: Sequence[Condition], repeats: int) -> tuple[Condition, ...]:
    if repeats < 1:
        raise ValueError(f"repeats must be at least 1, got {repeats}")
    return tuple(replace(c, repeat=r) for r in range(repeats) for c in conditions)


def single_force_plan(name: str, stretches: Sequence[float], forces: Sequence[float],
                      samples: int, skin: AnySkin = PAPER_SKIN, repeats: int = 1) -> ScenePlan:
    """Every stretch × force × node (node 0 being no contact, then every node of the skin),
    ``repeats`` times."""
    nodes = [(0, 0), *skin.nodes()]
    conditions = [Condition(float(s), (Contact(x, y, float(f)),))
                  for s in stretches for f in forces for x, y in nodes]
    return ScenePlan(name, ONE_CONTACT.name, _repeated(conditions, repeats), samples, skin,
                     repeats)


def two_force_plan(name: str, stretches: Sequence[float], forces: Sequence[float],
                   nodes_x: Sequence[int], nodes_y: Sequence[int], samples: int,
                   skin: AnySkin = PAPER_SKIN, repeats: int = 1,
                   contact_counts: Sequence[int] = (2,)) -> ScenePlan:
    """Every unordered pair of distinct nodes on the x × y grid, every force for each contact,
    ``repeats`` times. With 1 in ``contact_counts``, also every node of the grid pressed
    alone at every force; with 0, the skin untouched, once per stretch and force (a weight
    named and not placed, as a single-force plan's node 0). Those come after the pairs, so
    that the pairs' trials are the paper's plan's, whatever is added."""
    nodes = sorted((int(x), int(y)) for x in nodes_x for y in nodes_y)
    absent = Contact(0, 0, 0.0)
    conditions = [Condition(float(s), (Contact(*a, float(fa)), Contact(*b, float(fb))))
                  for s in stretches
                  for a, b in itertools.combinations(nodes, 2)  # a < b: a is contact 1
                  for fa in forces for fb in forces]
    if 1 in contact_counts:
        conditions += [Condition(float(s), (Contact(*a, float(f)), absent))
                       for s in stretches for a in nodes for f in forces]
    if 0 in contact_counts:
        conditions += [Condition(float(s), (Contact(0, 0, float(f)), absent))
                       for s in stretches for f in forces]
    return ScenePlan(name, TWO_CONTACTS.name, _repeated(conditions, repeats), samples, skin,
                     repeats)


def _single_force_plan_of(name: str, scene: AcquiredScene, skin: AnySkin) -> ScenePlan:
    return single_force_plan(name, [float(s) for s in scene.stretches],
                             [float(f) for f in scene.forces], scene.samples, skin,
                             scene.repeats)


def _two_force_plan_of(name: str, scene: AcquiredScene, skin: AnySkin) -> ScenePlan:
    return two_force_plan(name, [float(s) for s in scene.stretches],
                          [float(f) for f in scene.forces], scene.nodes_x, scene.nodes_y,
                          scene.samples, skin, scene.repeats,
                          scene.contact_counts or (TWO_CONTACTS.contacts,))


# Each scene kind's plan, from its checked params.yaml section, on the scene's skin: a new
# kind registers its own here.
PLANS: dict[str, Callable[[str, AcquiredScene, AnySkin], ScenePlan]] = {
    ONE_CONTACT.name: _single_force_plan_of, TWO_CONTACTS.name: _two_force_plan_of}


def plan_from_params(name: str, scene: AcquiredScene) -> ScenePlan:
    """The plan of scene ``name`` from its params.yaml section (``params.scenes[name]``),
    which :class:`eskin.config.AcquiredScene` has checked (kind, ranges, nodes, two-force
    levels), on the scene's skin (its kind's, :data:`PLANS`). An import scene has no plan:
    its labels are its files'."""
    return PLANS[scene.kind](name, scene, scene_skin(scene))
