"""data/processed/<scene>.parquet → data/features/<scene>.parquet + fitted transform."""

from __future__ import annotations

from pathlib import Path

from eskin.catalog import FEATURES_DIR, MODELS_DIR, PROCESSED_DIR
from eskin.config.base import DEFAULT_PARAMS, load_params, sections
from eskin.config.featurize import Featurize
from eskin.config.scenes import Scenes, get_scene
from eskin.learning.features import featurize_scene


def run(scene: str, params_path: Path | str = DEFAULT_PARAMS) -> str:
    params = load_params(sections(scenes=Scenes, featurize=Featurize), params_path)
    get_scene(params, scene, params_path)
    return featurize_scene(scene, PROCESSED_DIR, FEATURES_DIR, MODELS_DIR,
                           settings=params.featurize).summary
