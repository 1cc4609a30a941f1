"""A project copied (cp -a, with its mlflow.db and .venv) or cloned again works on its own:
its runs' artifacts land in its own mlruns/, never in the original's, and `make setup`
rebuilds a .venv made for another directory."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT, run_checked

# A pipeline's logging, as the publish stage does it: a pipeline run and an artifact on
# it (here a figure as its page), in the project's own store (the code under test:
# PYTHONPATH).
LOG_REPORT = """\
from pathlib import Path
from eskin.tracking import runs
figures = Path("figures")
figures.mkdir(exist_ok=True)
(figures / "force.svg").write_text(f"<svg><!-- {Path.cwd()} --></svg>")  # who wrote it
runs.track_pipeline(params={"sim": {"seed": 1}}, scenes=[], tasks=[], headline={},
                    page=figures / "force.svg")
"""


def project_env() -> dict:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MLFLOW_ENABLE_TELEMETRY": "false",
           "GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@t", "GIT_COMMITTER_NAME": "t",
           "GIT_COMMITTER_EMAIL": "t@t"}
    for own_store_hidden_by in ("MLFLOW_TRACKING_URI", "DVC_ROOT"):
        env.pop(own_store_hidden_by, None)
    return env


def log_a_report(project: Path, **env) -> str:
    """Log from ``project`` in a process of its own; its stderr."""
    done = run_checked([sys.executable, "-c", LOG_REPORT], project, {**project_env(), **env})
    return done.stderr


def files_in(directory: Path) -> dict[str, bytes]:
    return {str(path.relative_to(directory)): path.read_bytes()
            for path in sorted(directory.rglob("*")) if path.is_file()}


def figures_in(directory: Path) -> dict[str, bytes]:
    return {name: text for name, text in files_in(directory / "mlruns").items()
            if name.endswith("force.svg")}


@pytest.mark.heavy
def test_a_copied_project_and_a_second_clone_log_into_their_own_mlruns(tmp_path):
    original = tmp_path / "original"
    original.mkdir()
    env = project_env()
    (original / ".gitignore").write_text("mlflow.db\nmlruns/\nfigures/\nreport.html\n")
    for args in (["git", "init", "-q"], ["git", "add", "-A"], ["git", "commit", "-qm", "p"]):
        run_checked(args, original, env)
    log_a_report(original)
    before = files_in(original / "mlruns")
    assert len(figures_in(original)) == 1

    copy = tmp_path / "copy"
    run_checked(["cp", "-a", str(original), str(copy)], tmp_path, env)
    said = [log_a_report(copy), log_a_report(copy)]
    second = tmp_path / "second"
    run_checked(["git", "clone", "-q", str(original), str(second)], tmp_path, env)
    log_a_report(second)

    assert files_in(original / "mlruns") == before  # not a file added or rewritten
    copied = figures_in(original)
    own = {name: text for name, text in figures_in(copy).items() if name not in copied}
    assert list(own.values()) == [f"<svg><!-- {copy} --></svg>".encode()]
    assert list(figures_in(second).values()) == [f"<svg><!-- {second} --></svg>".encode()]
    # the copied experiment set aside, said once: the project's own is found next time
    assert f"renamed 'eskin (artifacts in {original / 'mlruns'})'" in said[0], said
    assert "renamed" not in said[1]


@pytest.mark.heavy
def test_a_queued_experiment_logs_into_the_projects_mlruns_not_its_temporary_copy(tmp_path):
    """`dvc exp run --queue` runs a stage in a copy of the project (.dvc/tmp/exps/...) with
    DVC_ROOT naming the project: the experiment made then keeps its artifacts in the
    project's mlruns/, not in the copy DVC deletes afterwards."""
    project, temporary_copy = tmp_path / "project", tmp_path / "project" / "exps" / "tmp1"
    temporary_copy.mkdir(parents=True)
    log_a_report(temporary_copy, DVC_ROOT=str(project))
    assert list(figures_in(project).values()) == [
        f"<svg><!-- {temporary_copy} --></svg>".encode()]
    assert not (temporary_copy / "mlruns").exists()


# ---------------------------------------------------------------- the .venv

def makefile_project(directory: Path, venv_made_for: Path) -> None:
    """The Makefile and what .venv/.installed depends on, and a .venv installed (up to
    date) whose pyvenv.cfg says where `python -m venv` made it."""
    directory.mkdir()
    for name in ("Makefile", "pyproject.toml", "constraints.txt"):
        shutil.copy2(ROOT / name, directory / name)
    venv = directory / ".venv"
    venv.mkdir()
    (venv / "pyvenv.cfg").write_text(
        f"home = /usr/bin\ncommand = /usr/bin/python3 -m venv {venv_made_for}\n")
    (venv / ".installed").touch()


def make_dry_run(directory: Path) -> subprocess.CompletedProcess:
    return subprocess.run(["make", "-n", ".venv/.installed"], cwd=directory, text=True,
                          capture_output=True, timeout=60)


@pytest.mark.starts
def test_make_setup_rebuilds_a_venv_made_for_another_directory(tmp_path):
    copied = tmp_path / "copied"
    makefile_project(copied, tmp_path / "original" / ".venv")
    planned = make_dry_run(copied)
    assert planned.returncode == 0, planned.stderr
    assert f".venv was made for {tmp_path / 'original' / '.venv'}: rebuilding it here" in \
        planned.stdout
    assert "rm -rf .venv" in planned.stdout.splitlines()
    assert "-m venv .venv" in planned.stdout


@pytest.mark.starts
def test_make_setup_keeps_a_venv_made_here():
    # (the real directory: make's CURDIR is the physical path, as venv's is)
    import tempfile

    with tempfile.TemporaryDirectory() as scratch:
        here = Path(scratch).resolve() / "here"
        makefile_project(here, here / ".venv")
        planned = make_dry_run(here)
    assert planned.returncode == 0, planned.stderr
    assert "rm -rf" not in planned.stdout and "pip install" not in planned.stdout, \
        planned.stdout
