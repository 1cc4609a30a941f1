"""DVC stage: a scene's trained stack → one ONNX file, checked against the scikit-learn stack."""

import sys

from eskin.config import get_scene, load_params
from eskin.deploy.export import export_scene
from eskin.errors import run_friendly


def main(scene: str) -> str:
    get_scene(load_params(), scene)
    return export_scene(scene)


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(sys.argv[1]))))
