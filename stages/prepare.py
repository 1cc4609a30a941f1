"""DVC stage: data/raw/<scene>/ → data/processed/<scene>.parquet (+ quarantine CSV and the
frames recorded live), data/features/<scene>.parquet (+ fitted transform) and
data/folds/<scene>.parquet: the ingest, featurize and folds steps, in one process."""

import sys

from eskin.errors import run_friendly
from eskin.steps import featurize, folds, ingest


def main(scene: str) -> str:
    return "\n".join(step.run(scene) for step in (ingest, featurize, folds))


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(sys.argv[1]))))
