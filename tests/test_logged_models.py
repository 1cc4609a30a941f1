"""A model logged to MLflow: its environment pinned, and MLflow's check of that environment
left out (issue 55: about 1.2 s a process that logs a model). A SQLite store in a scratch
directory, in this process: no server."""

from __future__ import annotations

import inspect
from importlib.metadata import version

import mlflow
import mlflow.sklearn
import mlflow.utils.environment
import mlflow.utils.requirements_utils as requirements_utils
import numpy as np
import pytest
from packaging.requirements import Requirement
from sklearn.linear_model import LinearRegression

from eskin.tracking.runs import pinned_environment, requirements


def test_the_pins_are_the_running_environments_so_the_check_left_out_would_pass():
    pins = requirements()
    assert {Requirement(pin).name for pin in pins} == {"scikit-learn", "numpy", "scipy",
                                                      "pandas"}
    for pin in pins:
        req = Requirement(pin)
        assert req.specifier.contains(version(req.name)), pin


def test_mlflow_still_checks_the_environment_by_the_name_left_out():
    # the name pinned_environment() replaces is the one MLflow calls as it logs a model
    source = inspect.getsource(mlflow.utils.environment._process_pip_requirements)
    assert "warn_dependency_requirement_mismatches(" in source


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> tuple[str, str]:
    """A SQLite store and an experiment in it, made once: MLflow's schema migrations are
    most of a store's first second."""
    uri = f"sqlite:///{tmp_path_factory.mktemp('store') / 'mlflow.db'}"
    return uri, mlflow.MlflowClient(uri).create_experiment("pinned")


@pytest.mark.parametrize("pinned", [False, True])
def test_logging_a_model_reads_the_installed_distributions_only_unpinned(store, monkeypatch,
                                                                          pinned):
    read = []
    scan = requirements_utils.importlib_metadata.packages_distributions
    monkeypatch.setattr(requirements_utils, "_MODULES_TO_PACKAGES", None)  # MLflow's memo
    monkeypatch.setattr(requirements_utils.importlib_metadata, "packages_distributions",
                        lambda: read.append(1) or scan())
    uri, experiment = store
    mlflow.set_tracking_uri(uri)  # no active experiment set: other tests' stays theirs
    try:
        X = np.arange(10.0).reshape(5, 2)
        model = LinearRegression().fit(X, X.sum(axis=1))
        with mlflow.start_run(experiment_id=experiment):
            if pinned:
                with pinned_environment():
                    info = mlflow.sklearn.log_model(model, name="m",
                                                    pip_requirements=requirements())
            else:
                info = mlflow.sklearn.log_model(model, name="m", pip_requirements=requirements())
        logged = mlflow.pyfunc.get_model_dependencies(info.model_uri)
    finally:
        mlflow.set_tracking_uri(None)
    assert bool(read) is not pinned
    lines = [line.strip() for line in open(logged).read().splitlines() if line.strip()]
    assert set(requirements()) <= set(lines)
    assert f"mlflow=={mlflow.__version__}" in lines
    # the original check is back once the block ends
    assert mlflow.utils.environment.warn_dependency_requirement_mismatches.__module__ == \
        "mlflow.utils.requirements_utils"
