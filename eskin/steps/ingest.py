"""data/raw/<scene>/ → data/processed/<scene>.parquet (+ quarantine CSV)."""

from __future__ import annotations

from pathlib import Path

from eskin.catalog import PROCESSED_DIR, RAW_DIR
from eskin.config.base import DEFAULT_PARAMS, load_params, sections
from eskin.config.ingest import Ingest
from eskin.config.scenes import Scenes, get_scene
from eskin.data import build


def run(scene: str, params_path: Path | str = DEFAULT_PARAMS) -> str:
    params = load_params(sections(scenes=Scenes, ingest=Ingest), params_path)
    return build.ingest(scene, get_scene(params, scene, params_path), RAW_DIR / scene,
                        PROCESSED_DIR, ingest=params.ingest).summary
