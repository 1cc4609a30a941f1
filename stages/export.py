"""DVC stage: a scene's trained stack → one ONNX file, checked against the scikit-learn stack."""

import sys

from eskin.errors import run_friendly
from eskin.export import export_scene

if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(export_scene(sys.argv[1]))))
