"""params.yaml: the one place every knob lives, read by section."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from eskin.acquisition.plan import ScenePlan, plan_from_params
from eskin.device.physics import SkinParams

DEFAULT_PARAMS = Path("params.yaml")


def load_params(path: Path = DEFAULT_PARAMS) -> dict[str, Any]:
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no params file (run from the project root)")
    with path.open() as handle:
        params = yaml.safe_load(handle)
    if not isinstance(params, dict):
        raise ValueError(f"{path}: expected a mapping of sections")
    return params


def section(params: Mapping[str, Any], dotted: str) -> Any:
    """``section(params, "scenes.single_force")``, with an error naming what is missing."""
    node: Any = params
    for i, part in enumerate(dotted.split(".")):
        if not isinstance(node, Mapping) or part not in node:
            where = ".".join(dotted.split(".")[:i + 1])
            raise KeyError(f"params.yaml has no {where}")
        node = node[part]
    return node


def scene_plan(params: Mapping[str, Any], scene: str) -> ScenePlan:
    return plan_from_params(scene, section(params, f"scenes.{scene}"))


def skin_params(params: Mapping[str, Any]) -> SkinParams:
    return SkinParams.from_mapping(section(params, "sim"))
