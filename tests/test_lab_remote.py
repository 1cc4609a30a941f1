"""A lab's DVC remote over SSH (`make lab-server`: Debian's OpenSSH server on 127.0.0.1,
eskin/tracking/lab.py): a clone pushes its outputs, a second clone with an empty cache
pulls them, runs no stage, and both `dvc status` and `git status` are clean.

The commands each clone runs are the ones `make lab-server` prints, run as printed."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from conftest import ROOT, run_checked

from eskin.tracking.lab import SSHD, free_port

# Each test here starts sshd and a pipeline: `make check` leaves them out.
pytestmark = [pytest.mark.starts,
              pytest.mark.skipif(not os.access(SSHD, os.X_OK),
                                 reason="Debian's openssh-server is missing: `make test` "
                                 "installs it")]


@pytest.fixture(scope="module")
def lab_remote():
    """`python -m eskin.tracking.lab serve` (what `make lab-server` runs) on free ports;
    yields (the commands it prints for a clone, the remote's directory). Stopped as a user
    stops it, with Ctrl-C."""
    home = Path(tempfile.mkdtemp(prefix="eskin-lab-"))  # postgres must reach it: not 0700
    home.chmod(0o755)
    serving = subprocess.Popen(
        [sys.executable, "-m", "eskin.tracking.lab", "serve", "--dir", str(home),
         "--port", str(free_port()), "--pg-port", str(free_port()),
         "--ssh-port", str(free_port())], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        text=True, env={**os.environ, "MLFLOW_TRACKING_URI": ""})
    lines: list[str] = []
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not any("Ctrl-C" in line for line in lines):
            line = serving.stdout.readline()
            if not line:
                break
            lines.append(line)
        commands = [line.strip() for line in lines if line.startswith("  dvc remote ")]
        assert len(commands) == 2, "".join(lines)
        yield commands, home / "dvc-remote"
    finally:
        serving.send_signal(signal.SIGINT)
        try:  # the stop's own deadlines: mlflow 30 s, pg_ctl 60 s, sshd 30 s
            serving.wait(timeout=150)
        except subprocess.TimeoutExpired:
            serving.kill()
            serving.wait(timeout=30)
        shutil.rmtree(home, ignore_errors=True)
    assert serving.returncode == 0, "".join(lines) + (serving.stdout.read() or "")


def clone_env(home: Path) -> dict:
    """A user's shell: the venv's dvc first, a home of its own (no ~/.ssh, no DVC config)."""
    home.mkdir(exist_ok=True)
    bin_dir = str(Path(sys.executable).parent)
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}",
           "HOME": str(home), "DVC_NO_ANALYTICS": "1", "GIT_AUTHOR_NAME": "t",
           "GIT_AUTHOR_EMAIL": "t@t", "GIT_COMMITTER_NAME": "t", "GIT_COMMITTER_EMAIL": "t@t"}
    for name in ("DVC_ROOT", "MLFLOW_TRACKING_URI"):
        env.pop(name, None)
    return env


def use_the_remote(clone: Path, commands: list[str], env: dict) -> None:
    for command in commands:  # as printed, in a shell
        run_checked(["bash", "-c", command], clone, env)


def assert_clean(clone: Path, env: dict) -> None:
    status = run_checked(["dvc", "status"], clone, env).stdout
    assert "Data and pipelines are up to date." in status, status
    assert run_checked(["git", "status", "--porcelain"], clone, env).stdout == ""


TRAIN = """\
import json, sys
from pathlib import Path

rows = Path("data/readings.csv").read_text().splitlines()
Path("models").mkdir(exist_ok=True)
Path("models/model.txt").write_text(f"mean of {len(rows)} rows\\n")
Path("scores.json").write_text(json.dumps({"rows": len(rows)}))
with open(sys.argv[1], "a") as ran:  # outside the project: every run of the stage, noted
    ran.write("train\\n")
"""


def test_a_second_clone_pulls_data_models_and_scores_instead_of_recomputing(lab_remote,
                                                                           tmp_path):
    commands, remote = lab_remote
    env = clone_env(tmp_path / "home")
    ran = tmp_path / "stage-runs.txt"
    first = tmp_path / "first"
    first.mkdir()
    (first / "data").mkdir()
    (first / "data" / "readings.csv").write_text("".join(f"{i},{i * i}\n" for i in range(500)))
    (first / "train.py").write_text(TRAIN)
    for args in (["git", "init", "-q"], ["dvc", "init", "-q"],
                 ["dvc", "add", "-q", "data/readings.csv"],
                 ["dvc", "stage", "add", "-q", "-n", "train", "-d", "data/readings.csv",
                  "-d", "train.py", "-o", "models", "-m", "scores.json",
                  f"python train.py {ran}"],
                 ["dvc", "repro", "-q"], ["git", "add", "-A"], ["git", "commit", "-qm", "p"]):
        run_checked(args, first, env)
    use_the_remote(first, commands, env)
    pushed = run_checked(["dvc", "push"], first, env).stdout
    assert "4 files pushed" in pushed, pushed  # the models directory: its listing too
    assert_clean(first, env)

    second = tmp_path / "second"
    run_checked(["git", "clone", "-q", str(first), str(second)], tmp_path, env)
    assert not (second / ".dvc" / "cache").exists()  # an empty cache
    use_the_remote(second, commands, env)
    pulled = run_checked(["dvc", "pull"], second, env).stdout
    assert "4 files fetched" in pulled, pulled
    for output in ("data/readings.csv", "models/model.txt", "scores.json"):
        assert (second / output).read_bytes() == (first / output).read_bytes()
    assert ran.read_text() == "train\n"  # once, in the first clone
    assert_clean(second, env)
    assert any(remote.rglob("*")), "nothing in the remote's directory"


def test_this_projects_outputs_go_through_the_lab_remote(lab_remote, tmp_path):
    """The pipeline's outputs (dvc.lock: data, models, scores, reports), from the
    repository's DVC cache to a second clone that pulls them."""
    commands, _ = lab_remote
    env = clone_env(tmp_path / "home")
    cache = run_checked(["dvc", "cache", "dir"], ROOT, env).stdout.strip()
    first, second = tmp_path / "first", tmp_path / "second"
    run_checked(["git", "clone", "-q", str(ROOT), str(first)], tmp_path, env)
    run_checked(["dvc", "cache", "dir", "--local", cache], first, env)
    checkout = run_checked(["dvc", "checkout", "-q"], first, env, ok=False)
    if checkout.returncode != 0:
        pytest.skip(f"the repository's DVC cache ({cache}) lacks dvc.lock's outputs: "
                    "`make repro` makes them")
    use_the_remote(first, commands, env)
    run_checked(["dvc", "push"], first, env)

    run_checked(["git", "clone", "-q", str(ROOT), str(second)], tmp_path, env)
    use_the_remote(second, commands, env)
    run_checked(["dvc", "pull"], second, env)
    assert_clean(second, env)
    # every output the first clone has, byte for byte
    outputs = run_checked(["dvc", "ls", "--dvc-only", "-R", "."], first, env).stdout.split()
    assert len(outputs) > 10
    for output in outputs:
        assert (second / output).read_bytes() == (first / output).read_bytes(), output
