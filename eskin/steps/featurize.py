"""data/processed/<scene>.parquet → data/features/<scene>.parquet + fitted transform.

:func:`featurize_at` reads and writes; the transform between is
:func:`eskin.learning.features.fit_featurizer` and :func:`~eskin.learning.features.featurize`,
which do neither."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import joblib

from eskin.catalog import FEATURES_DIR, MODELS_DIR, PROCESSED_DIR
from eskin.config.base import DEFAULT_PARAMS, load_params, sections
from eskin.config.featurize import Featurize
from eskin.config.scenes import Scenes, get_scene
from eskin.data.schema import (
    dataset_kind,
    dataset_skin,
    md5_file,
    read_dataset,
    read_metadata,
    write_dataset,
)
from eskin.learning.features import featurize, fit_featurizer


@dataclass(frozen=True)
class Featurized:
    """What :func:`featurize_at` wrote: the features and the fitted transform."""

    scene: str
    path: Path
    transform_path: Path
    rows: int
    method: str
    summary: str


def run(scene: str, params_path: Path | str = DEFAULT_PARAMS) -> str:
    params = load_params(sections(scenes=Scenes, featurize=Featurize), params_path)
    get_scene(params, scene, params_path)
    return featurize_at(scene, PROCESSED_DIR, FEATURES_DIR, MODELS_DIR,
                        settings=params.featurize).summary


def featurize_at(scene: str, processed_dir: Path, features_dir: Path, models_dir: Path, *,
                 settings: Featurize) -> Featurized:
    """``<processed>/<scene>.parquet`` → ``<features>/<scene>.parquet`` + the fitted
    transform, with the ``featurize`` section (``settings``), on the skin the dataset was
    taken on."""
    source = Path(processed_dir) / f"{scene}.parquet"
    if not source.exists():
        raise FileNotFoundError(f"{source}: no dataset; run `dvc repro prepare@{scene}` first")
    meta = read_metadata(source)
    frame = read_dataset(source)
    skin, kind = dataset_skin(source), dataset_kind(source)
    method = settings.method
    featurizer = fit_featurizer(method, frame, kind.name, skin)
    out = Path(features_dir) / f"{scene}.parquet"
    meta.update(featurize={"method": method},
                dataset={"path": source.as_posix(), "md5": md5_file(source), "rows": len(frame)})
    write_dataset(featurize(frame, featurizer, skin), kind.name, out, meta, skin=skin)
    transform = Path(models_dir) / scene / "featurizer.joblib"
    transform.parent.mkdir(parents=True, exist_ok=True)
    joblib.dump(featurizer, transform)
    return Featurized(scene, out, transform, len(frame), method,
                      f"{scene}: {len(frame)} rows featurized ({method}) → {out}")
