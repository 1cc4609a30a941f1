"""Numerical stress, reduced: every case of `make stress` on a small scene, the tuned and
paper models, and hypothesis rescalings of the default models' inputs."""

import copy

import numpy as np
import pandas as pd
import pytest
from conftest import acquire_step, featurize_step, ingest_step, small_scenes, typed
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from eskin.catalog import TASK_NAMES
from eskin.data.schema import read_dataset
from eskin.evaluation.tasks import get_task
from eskin.learning.choice import model_settings
from eskin.learning.estimators import build_model
from eskin.skin import PAPER_SKIN
from harness import stress

# Each test here trains the default models under numerical stress: `make check` leaves
# them out.
pytestmark = pytest.mark.heavy


def acquire_features(params, root):
    acquire_step(params, "single_force", root / "raw", progress=False)
    ingest_step(params, "single_force", root / "raw", root / "processed")
    featurize_step(params, "single_force", root / "processed", root / "features",
                   root / "models")
    return read_dataset(root / "features" / "single_force.parquet")


@pytest.fixture(scope="module")
def small(tmp_path_factory, repo_params):
    params = small_scenes(repo_params)
    params["train"]["force"]["paper"]["subsample"] = 300
    params["train"]["localise"]["paper"]["n_estimators"] = 20
    frames = {"default": acquire_features(params, tmp_path_factory.mktemp("stress"))}
    for name, factor in (("noise_zero", 0.0), ("noise_x10", 10.0)):
        noisy = copy.deepcopy(params)
        for knob in ("noise_pf", "drift_offset_pf"):
            noisy["sim"][knob] *= factor
        noisy["scenes"]["single_force"].update(samples=3)
        frames[name] = acquire_features(noisy, tmp_path_factory.mktemp(name))
    return params, frames


@pytest.fixture(scope="module")
def suite(small):
    params, frames = small
    return stress.run_suite(frames, typed(params), PAPER_SKIN, folds=3, log=lambda _: None)


def test_every_case_passes_or_ends_in_a_clear_error(suite):
    failed = [(r["case"], r["task"], r["model"], r["outcome"], r.get("error"))
              for r in suite if r["outcome"].startswith("FAIL")]
    assert failed == []
    models = {(r["task"], r["model"]) for r in suite}
    assert len(models) == 7  # tuned and paper models of the four single-force tasks
    assert {r["case"] for r in suite} == {c.name for c in stress.CASES}


def test_units_and_float32_leave_every_prediction_unchanged(suite):
    same = [r for r in suite if r["expect"] == "same" and r["case"] != "counts"]
    assert len(same) == 6 * 7
    for row in same:
        assert row["outcome"] == "pass"
        assert row.get("prediction_change", 0.0) <= stress.TOLERANCE["regression_prediction"]
        assert row.get("labels_changed", 0.0) == 0.0
        assert abs(row["score_delta"]) <= stress.TOLERANCE["score"]


def test_tiny_data_falls_back_to_coarser_strata_and_runs(suite):
    """40 samples, every node under 3 rows: the folds stratify on blocks of nodes (issue
    59; before, they refused the split) and every model runs to finite predictions."""
    tiny = [r for r in suite if r["case"] == "tiny"]
    assert {r["outcome"] for r in tiny} == {"pass"}


FORCE = get_task("single_force", "force")


def test_the_verdict_fails_what_it_should():
    case = stress.Case("x", "x", "same")
    reference = {"predictions": np.zeros((4, 1)), "truth": {"force": np.arange(4.0)},
                 "scores": {"force": {"r2": 0.5}}, "warnings": {}, "seconds": 1.0}
    moved = {**reference, "predictions": np.full((4, 1), 0.1)}
    assert stress.judge(case, moved, reference, FORCE)["outcome"] == \
        "FAIL: predictions changed"
    nan = {**reference, "predictions": np.full((4, 1), np.nan)}
    assert stress.judge(case, nan, reference, FORCE)["outcome"] == \
        "FAIL: non-finite predictions"
    flood = {**reference, "warnings": {"UserWarning: again": 50}}
    assert stress.judge(case, flood, reference, FORCE)["outcome"] == \
        "FAIL: warning flood"
    crash = {"error": "LinAlgError: not positive definite", "warnings": {}, "seconds": 0.0}
    for expect in ("same", "clear error"):
        verdict = stress.judge(stress.Case("x", "x", expect), crash, None, FORCE)
        assert verdict["outcome"] == "FAIL: error"
    assert stress.judge(case, reference, reference, FORCE)["outcome"] == "pass"


def test_the_exact_gp_factorises_a_large_matrix_of_repeated_samples(small):
    _, frames = small
    tripled = pd.concat([frames["default"]] * 3, ignore_index=True)  # singular without jitter
    # ≥ 4096 rows: the one-thread path
    row = stress.large_factorisation(tripled, 4500, seed=0, skin=PAPER_SKIN)
    assert row["outcome"] == "pass" and row["score"] > 0.5


@pytest.fixture(scope="module")
def default_fits(small):
    """The default (tuned) model of each single-force task and the rows it learns."""
    params, frames = small
    frame = frames["default"].iloc[::3].reset_index(drop=True)
    out = []
    for task_name in TASK_NAMES:
        section = getattr(typed(params).train, task_name)
        task = get_task("single_force", task_name)
        name, hyper = model_settings(section, "tuned")
        data = frame[task.rows(frame)]
        X = data[PAPER_SKIN.channels].astype(np.float64)  # by name: the x and y terminals
        target = next(iter(task.target_values(data).values()))
        model = build_model(task.role, name, hyper, PAPER_SKIN).fit(X, target)
        out.append((task_name, name, hyper, X, target, model.predict(X)))
    return out


@settings(max_examples=12, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(exponents=st.lists(st.floats(-12, 12), min_size=20, max_size=20))
def test_any_positive_rescaling_leaves_the_default_models_predictions(default_fits, exponents):
    scale = 10.0 ** np.asarray(exponents)
    for task_name, name, hyper, X, target, before in default_fits:
        role = get_task("single_force", task_name).role
        after = build_model(role, name, hyper, PAPER_SKIN).fit(X * scale, target).predict(
            X * scale)
        if np.issubdtype(np.asarray(before).dtype, np.floating):
            spread = np.std(target) or 1.0
            assert np.max(np.abs(after - before)) / spread <= 1e-6, (task_name, name)
        else:
            assert np.array_equal(after, before), (task_name, name)


def test_joblib_gets_a_working_pool_after_the_suite(suite):
    # The suite's worker pool is its own: joblib's Parallel in the same process (as the
    # next test on a pytest worker) must not be handed it.
    from joblib import Parallel, delayed

    assert Parallel(n_jobs=2, backend="loky")(delayed(abs)(-k) for k in range(4)) == [0, 1, 2, 3]
