"""A run left RUNNING by a killed stage is marked FAILED when next seen (issue 18, 9)."""

import subprocess
import sys

import pytest

from eskin.tracking import compare, connection, runs


@pytest.mark.heavy
def test_a_run_whose_process_died_is_marked_failed_and_audit_says_so(tmp_path, monkeypatch):
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow.db'}")
    monkeypatch.chdir(tmp_path)
    client = connection.connect()
    experiment_id = client.create_experiment(connection.EXPERIMENT,
                                             artifact_location=(tmp_path / "a").as_uri())
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    killed = client.create_run(experiment_id, tags={
        **runs.process_tags(), runs.PID_TAG: dead.stdout.strip(),
        "eskin.kind": "task", "eskin.scene": "single_force", "eskin.task": "force"})
    alive = client.create_run(experiment_id, tags={**runs.process_tags(),
                                                   "eskin.kind": "task"})
    elsewhere = client.create_run(experiment_id, tags={runs.PID_TAG: "1",
                                                       runs.HOST_TAG: "another-host"})
    table = compare.load_runs()
    status = dict(zip(table["run_id"], table["status"], strict=True))
    assert status[killed.info.run_id] == "FAILED"
    assert status[alive.info.run_id] == "RUNNING", "this process is alive"
    assert status[elsewhere.info.run_id] == "RUNNING", "another host's process is unknown"
    report = compare.run_audit(killed.info.run_id, tmp_path)
    state, detail = report["checks"]["run finished"]
    assert state == "FAILED" and "ended without closing the run" in detail
