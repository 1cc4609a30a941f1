"""A scene's trained stack → one ONNX file, checked against the scikit-learn stack."""

from __future__ import annotations

from pathlib import Path

from eskin.config.base import DEFAULT_PARAMS, load_params, sections
from eskin.config.scenes import Scenes, get_scene
from eskin.deploy.export import export_scene


def run(scene: str, params_path: Path | str = DEFAULT_PARAMS) -> str:
    get_scene(load_params(sections(scenes=Scenes), params_path), scene, params_path)
    return export_scene(scene)
