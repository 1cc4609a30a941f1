"""DVC stage of `make stress`: the numerical stress suite (harness/stress.py) on one
scene (skipped, with the reason, where the cases do not apply)."""

import sys
import tempfile

from eskin.catalog import STRESS_DIR, features_path
from eskin.config import STRESS_PARAMS, StressParams, get_scene, load_params
from eskin.errors import run_friendly
from harness import stress


def main(scene: str) -> str:
    params = load_params()
    get_scene(params, scene)
    settings = load_params(STRESS_PARAMS, StressParams).stress
    with tempfile.TemporaryDirectory(prefix="eskin-stress-") as scratch:
        return stress.stress(params, settings, scene, features_path(scene), STRESS_DIR,
                             scratch=scratch)


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(sys.argv[1]))))
