"""A task's saved models: written by training, loaded by the stack, the registry and
``eskin reproduce``, only by the md5 recorded for them (unpickling runs the code a file
names). Apart from training, so that loading a model does not import it."""

from __future__ import annotations

from pathlib import Path

import joblib

from eskin.data.schema import md5_file


def save_models(models: dict, path: Path) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    joblib.dump(models, path)


class ModelIntegrityError(ValueError):
    """A saved model whose bytes are not the ones recorded for it."""


def load_models(path: Path, md5: str) -> dict:
    """A task's saved models (target → estimator), unpickled only if the file's md5 is
    ``md5``, the one DVC (dvc.lock) and MLflow (``eskin.model_md5``) recorded for it:
    unpickling runs whatever code the file names."""
    actual = md5_file(path)
    if actual != md5:
        raise ModelIntegrityError(f"{path}: md5 is {actual}, but {md5} was recorded for this "
                                  "model; not loading it")
    return joblib.load(path)
