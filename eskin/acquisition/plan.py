"""Scenes as plans: the ordered list of conditions an experiment records.

A condition is what determines a trial: the stretch and the contacts (node
and force of each indenter). Its key adds the device (id and firmware), so a
condition recorded once on a device is never recorded again on it — when a
plan grows, only the new conditions are acquired — while another device, or
a simulator with other settings, starts afresh.

Label conventions (docs/scenes.md):

* single force — node 0 means "no indenter on the skin". As in the paper's
  data, node 0 is recorded at every force level and every node at 0 N; a
  sample is a contact only when force > 0 and node > 0.
* two forces — contact 1 is the contact whose node comes first in row-major
  order (lower x, then lower y); contact 2 is the other.
"""

from __future__ import annotations

import hashlib
import itertools
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from eskin.config import scene_skin
from eskin.kinds import KINDS, ONE_CONTACT, TWO_CONTACTS
from eskin.skin import PAPER_SKIN, AnySkin

if TYPE_CHECKING:
    from eskin.config import AcquiredScene


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
    stretch: float
    contacts: tuple[Contact, ...]

    def as_dict(self) -> dict[str, object]:
        return {"stretch": self.stretch,
                "contacts": [[c.x, c.y, c.force] for c in self.contacts]}

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> Condition:
        contacts = tuple(Contact(int(x), int(y), float(f)) for x, y, f in data["contacts"])
        return cls(float(data["stretch"]), contacts)

    def key(self, device_id: str, firmware: str) -> str:
        """Stable id of this condition on this device (16 hex digits)."""
        canonical = {"device": device_id, "firmware": firmware,
                     "stretch": round(self.stretch, 6),
                     "contacts": [[c.x, c.y, round(c.force, 6)] for c in self.contacts]}
        blob = json.dumps(canonical, sort_keys=True).encode()
        return hashlib.sha256(blob).hexdigest()[:16]

    def describe(self) -> str:
        touching = [c for c in self.contacts if c.touches]
        where = " + ".join(f"{c.force:g} N on ({c.x},{c.y})" for c in touching) or "no contact"
        return f"λ={self.stretch:g}, {where}"


@dataclass(frozen=True)
class ScenePlan:
    name: str
    kind: str
    conditions: tuple[Condition, ...]
    samples: int
    skin: AnySkin = PAPER_SKIN

    @property
    def n_samples(self) -> int:
        return len(self.conditions) * self.samples

    def as_dict(self) -> dict[str, object]:
        return {"name": self.name, "kind": self.kind, "samples": self.samples,
                "conditions": len(self.conditions)}


def single_force_plan(name: str, stretches: Sequence[float], forces: Sequence[float],
                      samples: int, skin: AnySkin = PAPER_SKIN) -> ScenePlan:
    """Every stretch × force × node (node 0 being no contact, then every node of the skin)."""
    nodes = [(0, 0), *skin.nodes()]
    conditions = tuple(
        Condition(float(s), (Contact(x, y, float(f)),))
        for s in stretches for f in forces for x, y in nodes)
    return ScenePlan(name, ONE_CONTACT.name, conditions, samples, skin)


def two_force_plan(name: str, stretches: Sequence[float], forces: Sequence[float],
                   nodes_x: Sequence[int], nodes_y: Sequence[int], samples: int,
                   skin: AnySkin = PAPER_SKIN) -> ScenePlan:
    """Every unordered pair of distinct nodes on the x × y grid, every force for each contact."""
    nodes = sorted((int(x), int(y)) for x in nodes_x for y in nodes_y)
    conditions = tuple(
        Condition(float(s), (Contact(*a, float(fa)), Contact(*b, float(fb))))
        for s in stretches
        for a, b in itertools.combinations(nodes, 2)  # a < b: a is contact 1
        for fa in forces for fb in forces)
    return ScenePlan(name, TWO_CONTACTS.name, conditions, samples, skin)


def plan_from_params(name: str, scene: AcquiredScene) -> ScenePlan:
    """The plan of scene ``name`` from its params.yaml section (``params.scenes[name]``),
    which :class:`eskin.config.AcquiredScene` has checked (kind, ranges, nodes, two-force
    levels), on the scene's skin. An import scene has no plan: its labels are its files'."""
    skin = scene_skin(scene)
    stretches = [float(s) for s in scene.stretches]
    forces = [float(f) for f in scene.forces]
    if KINDS[scene.kind].contacts == 1:
        return single_force_plan(name, stretches, forces, scene.samples, skin)
    return two_force_plan(name, stretches, forces, scene.nodes_x, scene.nodes_y, scene.samples,
                          skin)
