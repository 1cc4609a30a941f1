"""The loop's yardstick (harness/plain_fits.py) runs the very fits the training stage
runs: the same estimator on the same rows and folds gives the same out-of-fold
predictions as the pipeline's, here on a small simulated scene."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from conftest import featurize_step, prepared_scene, train_step, typed

from harness.plain_fits import fit_task


@pytest.mark.heavy
def test_the_plain_fits_predict_what_the_training_stage_predicted(small_params, tmp_path):
    prepared_scene(small_params, "single_force", tmp_path)
    featurize_step(small_params, "single_force", tmp_path / "processed",
                   tmp_path / "data" / "features", tmp_path / "models")
    predictions = tmp_path / "force.parquet"
    trained = train_step(small_params, "single_force", "force", tmp_path / "data" / "features",
                         folds_path=tmp_path / "data" / "folds" / "single_force.parquet",
                         scores_path=tmp_path / "force.json", predictions_path=predictions,
                         model_path=tmp_path / "force.joblib")
    assert trained.status == "trained"
    plain = fit_task(typed(small_params), "single_force", "force", tmp_path, keep=True)
    assert not plain["skipped"] and plain["model"] == trained.model
    oof = pd.read_parquet(predictions)
    assert set(plain["predictions"]) == set(oof["scheme"])
    for scheme, by_fold in plain["predictions"].items():
        rows = oof[oof["scheme"] == scheme]
        for fold, values in by_fold.items():
            tested = rows[rows["fold"] == fold]
            assert len(tested) > 0
            for target, predicted in zip(plain["targets"], values, strict=True):
                np.testing.assert_allclose(predicted, tested[f"{target}_pred"].to_numpy(
                    dtype=float), rtol=1e-9, err_msg=f"{scheme} fold {fold} {target}")
