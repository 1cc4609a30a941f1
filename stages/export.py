"""DVC stage: a scene's trained stack → one ONNX file, checked against the scikit-learn stack."""

import sys

from eskin.config.base import load_params, sections
from eskin.config.scenes import Scenes, get_scene
from eskin.deploy.export import export_scene
from eskin.errors import run_friendly


def main(scene: str) -> str:
    get_scene(load_params(sections(scenes=Scenes)), scene)
    return export_scene(scene)


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(sys.argv[1]))))
