"""DVC stage: data/features/<scene>.parquet → data/folds/<scene>.parquet, every CV scheme's
folds drawn once, so that no training stage draws them again."""

import sys

from eskin.catalog import features_path, folds_path
from eskin.config.base import load_params, sections
from eskin.config.cv import CV
from eskin.config.scenes import Scenes, get_scene
from eskin.errors import run_friendly
from eskin.evaluation.folds import write_scene_folds


def main(scene: str) -> str:
    params = load_params(sections(scenes=Scenes, cv=CV))
    get_scene(params, scene)
    return write_scene_folds(features_path(scene), folds_path(scene),
                             schemes=list(params.cv.schemes), n_splits=int(params.cv.folds),
                             seed=int(params.cv.seed), scene=scene)


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(sys.argv[1]))))
