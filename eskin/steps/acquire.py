"""Acquire one scene into data/raw/<scene>/ (resumes; reuses what is recorded)."""

from __future__ import annotations

from pathlib import Path

from eskin.acquisition import acquire
from eskin.catalog import RAW_DIR
from eskin.config.acquisition import Acquire, Sim, SimBoard
from eskin.config.base import DEFAULT_PARAMS, load_params, sections, validating
from eskin.config.cv import CV
from eskin.config.scenes import Scenes, get_scene


def run(scene: str, params_path: Path | str = DEFAULT_PARAMS, *, source: str | None = None,
        port: str | None = None, progress: bool = True) -> str:
    """``source`` and ``port`` (``eskin acquire --source/--port``) override the scene's."""
    params = load_params(sections(sim=Sim, sim_board=SimBoard, acquire=Acquire,
                                  scenes=Scenes, cv=CV), params_path)
    settings = get_scene(params, scene, params_path)
    override = {key: value for key, value in (("source", source), ("port", port)) if value}
    if override:
        settings = settings.model_copy(update=override)
    with validating():  # every scene is checked, but only this one's settings are used
        acquire.check_scenes({**params.scenes, scene: settings}, params.cv)
    return acquire.acquire(scene, settings, RAW_DIR / scene, acquire=params.acquire,
                           sim=params.sim, board=params.sim_board, progress=progress).summary
