"""DVC stage: a scene's trained stack → one ONNX file, checked against the scikit-learn stack."""

import sys

from eskin.errors import run_friendly
from eskin.steps.export import run as main

if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(sys.argv[1]))))
