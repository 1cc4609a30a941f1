"""DVC stage: data/raw/<scene>/ → data/processed/<scene>.parquet (+ quarantine CSV)."""

import sys

from eskin.catalog import PROCESSED_DIR, RAW_DIR
from eskin.config.base import load_params, sections
from eskin.config.ingest import Ingest
from eskin.config.scenes import Scenes, get_scene
from eskin.data import build
from eskin.errors import run_friendly


def main(scene: str) -> str:
    params = load_params(sections(scenes=Scenes, ingest=Ingest))
    return build.ingest(scene, get_scene(params, scene), RAW_DIR / scene, PROCESSED_DIR,
                        ingest=params.ingest).summary


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(sys.argv[1]))))
