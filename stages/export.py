"""DVC stage: a scene's trained stack → one ONNX file, checked against the scikit-learn stack."""

import sys

from eskin.deploy.export import export_scene
from eskin.errors import run_friendly

if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(export_scene(sys.argv[1]))))
