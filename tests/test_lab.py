"""A lab's scale: cross-validation on a real dask.distributed cluster (a scheduler and
two worker processes on 127.0.0.1, started here) against loky.

The lab's tracking server (PostgreSQL under ``mlflow server --serve-artifacts``,
eskin/tracking/lab.py) is the one tests/test_pipeline_tracking.py runs the whole pipeline,
concurrent experiments from two clones and a database lost mid-run against.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
import time

import pandas as pd
import pytest

from eskin.evaluation.crossval import cross_validate, parallel_backend
from eskin.evaluation.folds import assign_folds
from eskin.evaluation.tasks import get_task
from eskin.learning.estimators import build_model
from eskin.skin import PAPER_SKIN
from tests.conftest import prepared_scene, small_scenes

# ---------------------------------------------------------------- Dask


@pytest.fixture(scope="module")
def cluster():
    """A scheduler and two worker processes (one thread each) on 127.0.0.1."""
    from distributed import Client, LocalCluster

    from harness.dask_scaling import ShippedData

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None, silence_logs=logging.ERROR) as local, \
            Client(local, timeout=60) as client:
        client.register_plugin(ShippedData())
        yield local, client


@pytest.fixture(scope="module")
def dataset(tmp_path_factory, repo_params):
    params = small_scenes(repo_params)
    return pd.read_parquet(prepared_scene(params, "single_force",
                                          tmp_path_factory.mktemp("dask")))


def cv_on(backend: str, frame: pd.DataFrame, n_jobs: int = 2,
          model: str = "hist_gradient_boosting"):
    task = get_task("single_force", "force")
    folds = assign_folds(frame, "single_force", "conditions", 10, 42, skin=PAPER_SKIN)
    hyper = {"max_iter": 60} if model == "hist_gradient_boosting" else {"n_estimators": 30}
    estimator = build_model("force", model, {**hyper, "seed": 0})
    with parallel_backend(backend):
        return cross_validate(task, frame, folds, estimator, "conditions", PAPER_SKIN,
                              n_jobs=n_jobs)


@pytest.mark.heavy
def test_dask_gives_the_predictions_of_loky_and_ships_the_features_once(cluster, dataset,
                                                                         monkeypatch):
    from harness.dask_scaling import clear, shipped

    local, client = cluster
    reference = cv_on("loky", dataset)
    clear(client)
    # As a lab points the pipeline at its cluster: by address, no client of our own open
    monkeypatch.setenv("DASK_SCHEDULER_ADDRESS", local.scheduler_address)
    result = cv_on("dask", dataset, n_jobs=-1)
    pd.testing.assert_frame_equal(result.predictions, reference.predictions)
    sent = shipped(client)  # per task: joblib's batch of folds
    assert sent["tasks"] >= 2
    features = len(dataset) * 20 * 8  # rows × 20 channels, float64
    assert sent["shared_bytes"] >= features  # the features and targets: in every task ...
    assert sent["own_bytes_per_task"] == 0  # ... and nothing else of size in any


@pytest.mark.alone
def test_a_worker_killed_mid_sweep_and_the_sweep_completes_on_the_other(cluster, dataset):
    _, client = cluster
    killed: list[tuple[str, float]] = []

    def kill_a_busy_worker():
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            busy = [worker for worker, keys in client.processing().items() if keys]
            if busy:  # a fold under way there: kill it mid-fold
                killed.append((busy[0], time.monotonic()))
                with contextlib.suppress(Exception):  # it dies before it can answer
                    client.run(lambda: os.kill(os.getpid(), signal.SIGKILL), workers=busy[:1])
                return
            time.sleep(0.01)

    killer = threading.Thread(target=kill_a_busy_worker)
    killer.start()
    result = cv_on("dask", dataset, n_jobs=-1, model="random_forest")
    done = time.monotonic()
    killer.join()
    assert killed and killed[0][1] < done  # it died while the sweep ran
    assert killed[0][0] not in client.scheduler_info()["workers"]
    pd.testing.assert_frame_equal(result.predictions,
                                  cv_on("loky", dataset, model="random_forest").predictions)


@pytest.mark.heavy
def test_an_unreachable_scheduler_is_one_line_naming_it(monkeypatch):
    monkeypatch.setattr("eskin.evaluation.crossval.DASK_CONNECT_S", 2)
    with socket_closed() as address:
        monkeypatch.setenv("DASK_SCHEDULER_ADDRESS", address)
        with pytest.raises(ValueError, match=f"no Dask scheduler answered at {address}"):
            parallel_backend("dask")


class socket_closed:
    """The address of a loopback port nobody listens on."""

    def __enter__(self) -> str:
        from eskin.tracking.lab import free_port

        return f"tcp://127.0.0.1:{free_port()}"

    def __exit__(self, *exc) -> None:
        pass


# ---------------------------------------------------------------- the tracking server


@pytest.mark.starts
def test_a_ctrl_c_as_the_lab_server_says_how_to_stop_it_is_a_clean_stop(monkeypatch, tmp_path):
    """Ctrl-C at the moment `make lab-server` prints "Ctrl-C stops them." (as a user, or the
    test below, answers that line): exit 0 and every server stopped, not "interrupted" (130).
    The fresh-clone CI of 799af58 caught that window, once, under load."""
    from types import SimpleNamespace

    import eskin.tracking.connection
    import eskin.tracking.lab

    stopped = []

    @contextlib.contextmanager
    def servers(directory, **ports):
        process = SimpleNamespace(poll=lambda: None)
        try:
            yield (SimpleNamespace(uri="postgresql://db"),
                   SimpleNamespace(uri="http://127.0.0.1:5999", artifacts=directory,
                                   process=process, log=directory / "log"))
        finally:
            stopped.append(directory)

    def ctrl_c_on_the_line_that_names_it(*args, **kwargs):
        if "Ctrl-C" in " ".join(map(str, args)):
            raise KeyboardInterrupt

    @contextlib.contextmanager
    def remote(directory, **port):
        try:
            yield SimpleNamespace(port=2222, objects=directory, clone_commands=lambda: [])
        finally:
            stopped.append("remote")

    monkeypatch.setattr(eskin.tracking.lab, "lab_server", servers)
    monkeypatch.setattr(eskin.tracking.lab, "data_remote", remote)
    monkeypatch.setattr(eskin.tracking.connection, "ensure_experiment", lambda: "1")
    monkeypatch.setattr(eskin.tracking.lab, "print", ctrl_c_on_the_line_that_names_it,
                        raising=False)
    monkeypatch.setenv("MLFLOW_TRACKING_URI", "")
    assert eskin.tracking.lab.main(["serve", "--dir", str(tmp_path)]) == 0
    assert stopped == ["remote", tmp_path]


@pytest.mark.heavy
def test_make_lab_server_names_the_training_view_of_its_experiment():
    """`make lab-server` (python -m eskin.tracking.lab serve) prints the link to the experiment's
    runs in MLflow's training view, the experiment made already; Ctrl-C stops it."""
    import json
    import re
    import shutil
    import subprocess
    import sys
    import tempfile
    import urllib.request
    from pathlib import Path

    from eskin.tracking.lab import free_port

    home = Path(tempfile.mkdtemp(prefix="eskin-lab-"))  # postgres must reach it: not 0700
    home.chmod(0o755)
    port = free_port()
    serving = subprocess.Popen(
        [sys.executable, "-m", "eskin.tracking.lab", "serve", "--dir", str(home),
         "--port", str(port),
         "--pg-port", str(free_port()), "--ssh-port", str(free_port())],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        text=True, env={**os.environ, "MLFLOW_TRACKING_URI": ""})
    lines: list[str] = []
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not any("Ctrl-C" in line for line in lines):
            line = serving.stdout.readline()
            if not line:
                break
            lines.append(line)
        printed = "".join(lines)
        found = re.search(r"The training runs: (\S+)", printed)
        assert found, printed
        assert re.fullmatch(rf"http://127\.0\.0\.1:{port}/#/experiments/\d+"
                            r"\?workflowType=machine_learning", found.group(1)), printed
        experiment = found.group(1).split("/experiments/")[1].split("?")[0]
        with urllib.request.urlopen(
                f"http://127.0.0.1:{port}/api/2.0/mlflow/experiments/get?experiment_id="
                f"{experiment}", timeout=30) as answer:
            made = json.loads(answer.read())["experiment"]
        assert made["name"] == "eskin"
        assert {"key": "mlflow.experimentKind", "value": "custom_model_development"} in \
            made["tags"]
    finally:
        serving.send_signal(signal.SIGINT)
        try:  # the stop's own deadlines: mlflow 30 s, pg_ctl 60 s, sshd 30 s
            serving.wait(timeout=150)
        except subprocess.TimeoutExpired:
            serving.kill()
            serving.wait(timeout=30)
        shutil.rmtree(home, ignore_errors=True)
    assert serving.returncode == 0, "".join(lines) + (serving.stdout.read() or "")
