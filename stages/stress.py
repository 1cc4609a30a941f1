"""DVC stage of `make stress`: the numerical stress suite (harness/stress.py) on one
scene (skipped, with the reason, where the cases do not apply)."""

import sys
import tempfile

from eskin.catalog import STRESS_DIR, features_path
from eskin.config.base import load_params
from eskin.config.params import Params
from eskin.config.scenes import get_scene
from eskin.errors import run_friendly
from harness import stress
from harness.params import StressParams


def main(scene: str) -> str:
    params = load_params(Params)
    get_scene(params, scene)
    settings = load_params(StressParams).stress
    with tempfile.TemporaryDirectory(prefix="eskin-stress-") as scratch:
        return stress.stress(params, settings, scene, features_path(scene), STRESS_DIR,
                             scratch=scratch)


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(sys.argv[1]))))
