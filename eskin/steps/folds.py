"""data/features/<scene>.parquet → data/folds/<scene>.parquet, every CV scheme's folds
drawn once, so that no training step draws them again."""

from __future__ import annotations

from pathlib import Path

from eskin.catalog import features_path, folds_path
from eskin.config.base import DEFAULT_PARAMS, load_params, sections
from eskin.config.cv import CV
from eskin.config.scenes import Scenes, get_scene
from eskin.evaluation.folds import write_scene_folds


def run(scene: str, params_path: Path | str = DEFAULT_PARAMS) -> str:
    params = load_params(sections(scenes=Scenes, cv=CV), params_path)
    get_scene(params, scene, params_path)
    return write_scene_folds(features_path(scene), folds_path(scene),
                             schemes=list(params.cv.schemes), n_splits=int(params.cv.folds),
                             seed=int(params.cv.seed), scene=scene)
