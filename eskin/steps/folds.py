"""data/features/<scene>.parquet → data/folds/<scene>.parquet, every CV scheme's folds
drawn once, so that no training step draws them again.

:func:`folds_at` reads and writes; the drawing between is
:func:`eskin.evaluation.folds.draw_scene_folds`, which does neither."""

from __future__ import annotations

from pathlib import Path

from eskin.catalog import features_path, folds_path
from eskin.config.base import DEFAULT_PARAMS, load_params, sections
from eskin.config.cv import CV
from eskin.config.scenes import Scenes, get_scene
from eskin.data.schema import dataset_kind, dataset_skin, read_dataset
from eskin.evaluation.folds import draw_scene_folds


def run(scene: str, params_path: Path | str = DEFAULT_PARAMS) -> str:
    params = load_params(sections(scenes=Scenes, cv=CV), params_path)
    get_scene(params, scene, params_path)
    return folds_at(features_path(scene), folds_path(scene),
                    schemes=list(params.cv.schemes), n_splits=int(params.cv.folds),
                    seed=int(params.cv.seed), scene=scene)


def folds_at(features: Path, out: Path, *, schemes: list[str], n_splits: int, seed: int,
             scene: str) -> str:
    """The features at ``features`` → every scheme's fold numbers at ``out``
    (:func:`~eskin.evaluation.folds.draw_scene_folds`); returns what was drawn, and how
    any scheme fell back."""
    folds = draw_scene_folds(read_dataset(features), dataset_kind(features).name,
                             dataset_skin(features), schemes=schemes, n_splits=n_splits,
                             seed=seed, scene=scene, where=str(features))
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    folds.table.to_parquet(out, index=False)
    return folds.summary
