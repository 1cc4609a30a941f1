"""A new user's first `dvc repro`: the publish stage runs where the MLflow store is new,
even though dvc.lock (from git) already holds its deps, and a second `dvc repro` logs
nothing twice."""

from __future__ import annotations

import shutil

import mlflow
import pytest
from conftest import copy_small_pipeline, run_checked

from eskin.catalog import TRACKED

# Each test here starts a pipeline or a server: `make check` leaves them out.
pytestmark = pytest.mark.starts


def _runs(uri: str) -> list:
    client = mlflow.MlflowClient(tracking_uri=uri)
    experiment = client.get_experiment_by_name("eskin")
    return [] if experiment is None else client.search_runs([experiment.experiment_id],
                                                           max_results=1000)


def test_a_clone_with_the_lock_and_an_empty_store_logs_once(small_pipeline, tmp_path):
    # What a fresh clone has: dvc.lock and the pipeline's outputs as the lock records them,
    # no MLflow store and no tracking record (both ignored by git).
    root = tmp_path / "clone"
    uri = f"sqlite:///{tmp_path / 'new.db'}"
    env = copy_small_pipeline(small_pipeline, root, uri, track=False)
    (root / TRACKED).unlink()
    shutil.rmtree(root / "mlruns", ignore_errors=True)
    assert run_checked(["git", "status", "--porcelain"], root, env).stdout == ""

    first = run_checked(["dvc", "repro"], root, env).stdout
    assert "Running stage 'publish'" in first, first
    # only the views ran (the report again, then the tracking): every other output was
    # already what the lock says
    assert first.count("Running stage") == 1, first
    logged = _runs(uri)
    kinds = sorted(run.data.tags["eskin.kind"] for run in logged)
    # 4 single-force tasks, 3 two-force ones (its stretch skips: one stretch level)
    assert kinds.count("pipeline") == 1 and kinds.count("task") == 7, kinds
    # the lock did not move: the record says what was logged, not when or where
    assert run_checked(["git", "status", "--porcelain"], root, env).stdout == ""

    second = run_checked(["dvc", "repro"], root, env).stdout
    assert "Running stage" not in second, second
    assert len(_runs(uri)) == len(logged)


def test_an_empty_store_after_tracking_names_the_command_that_fills_it(small_pipeline,
                                                                      tmp_path):
    # The user deleted mlflow.db after a repro: `dvc repro` would skip the publish stage,
    # so the error names the one that runs it.
    root = tmp_path / "used"
    env = copy_small_pipeline(small_pipeline, root, f"sqlite:///{tmp_path / 'gone.db'}",
                              track=False)
    answer = run_checked(["eskin", "compare"], root, env, ok=False)
    assert answer.returncode == 1
    told = answer.stderr.strip().splitlines()
    assert len(told) == 1 and "`dvc repro --force --single-item publish`" in told[0], told
    run_checked(["dvc", "repro", "--force", "--single-item", "publish"], root, env)
    assert run_checked(["eskin", "compare"], root, env).returncode == 0
