"""make bench's lock_interrupts (harness/lock_interrupts.py) on a small DVC project of its
own: the stub it makes of a pipeline, how it tells a lock after a Ctrl-C, and both arms
on two Ctrl-Cs."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from harness.lock_interrupts import ARMS, OUTCOMES, measure, outcome, render, stub_project

PIPELINE = """stages:
  make_dir:
    cmd: python work.py dir
    deps: [work.py]
    params: [knob]
    outs: [outdir]
  read_dir:
    cmd: python work.py read
    deps: [work.py, outdir/inner.txt]
    outs: [read.txt]
  last:
    cmd: python work.py last
    deps: [read.txt]
    outs: [last.txt]
"""
WORK = """import sys
from pathlib import Path
step = sys.argv[1]
if step == "dir":
    Path("outdir").mkdir(exist_ok=True)
    (Path("outdir") / "inner.txt").write_text("in")
    (Path("outdir") / "other.txt").write_text("other")
else:
    Path(f"{step}.txt").write_text(step)
"""
ENV = {**os.environ, "GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@t",
       "GIT_COMMITTER_NAME": "t", "GIT_COMMITTER_EMAIL": "t@t", "DVC_NO_ANALYTICS": "1",
       "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    """A pipeline as the project is one: its code, params and lock committed to git."""
    root = tmp_path_factory.mktemp("root")
    (root / "dvc.yaml").write_text(PIPELINE)
    (root / "work.py").write_text(WORK)
    (root / "params.yaml").write_text("knob: 1\n")
    for args in (["git", "init", "-q"], ["dvc", "init", "-q"], ["dvc", "repro", "-q"],
                 ["git", "add", "-A"], ["git", "commit", "-qm", "pipeline"]):
        subprocess.run(args, cwd=root, env=ENV, check=True, capture_output=True, timeout=120)
    return root


def test_the_stub_has_the_pipelines_stages_and_writes_what_the_next_ones_read(root, tmp_path):
    found = stub_project(tmp_path / "stub", root=root)
    stub = tmp_path / "stub"
    assert found["stages"] == 3
    assert {stage["cmd"] for stage in yaml.safe_load((stub / "dvc.yaml").read_text())[
        "stages"].values()} == {"python stub.py"}
    # a directory output: the file of it a later stage reads; a file output: itself
    assert json.loads((stub / "stub_outputs.json").read_text()) == {
        "make_dir": ["outdir/inner.txt"], "read_dir": ["read.txt"], "last": ["last.txt"]}
    lock = yaml.safe_load((stub / "dvc.lock").read_text())["stages"]
    assert list(lock) == ["make_dir", "read_dir", "last"]
    assert lock["make_dir"]["outs"][0]["md5"].endswith(".dir")
    assert lock["make_dir"]["params"] == {"params.yaml": {"knob": 1}}
    committed = subprocess.run(["git", "show", "HEAD:dvc.lock"], cwd=stub, env=ENV,
                               capture_output=True, text=True, check=True).stdout
    assert committed == (stub / "dvc.lock").read_text()
    assert found["lock_bytes"] == len(committed.encode())

    reference = yaml.safe_load(committed)
    lock_file = stub / "dvc.lock"
    assert outcome(lock_file, reference)["outcome"] == "whole"
    lock_file.write_text("")
    assert outcome(lock_file, reference) | {"problem": None} == {
        "bytes": 0, "outcome": "empty", "problem": None, "ends": ""}
    lock_file.write_text(committed[:committed.index("\n  read_dir:\n") + 1])
    cut = outcome(lock_file, reference)
    assert (cut["outcome"], cut["stages_wrong"]) == ("cut", 2)
    assert "are gone (last, read_dir)" in cut["problem"]
    lock_file.write_text(committed[:committed.index("md5:") + 3])  # "md5" a key, no value
    assert outcome(lock_file, reference)["outcome"] == "unreadable"


def test_both_arms_on_the_same_seeded_ctrl_cs(root):
    result = measure(trials=2, seed=1, root=root, log=lambda line: None)
    for arm in ARMS:
        runs = result[arm]["runs"]
        assert [run["at"] / result[arm]["full_seconds"] for run in runs] == pytest.approx(
            [run["at"] / result["before"]["full_seconds"] for run in result["before"]["runs"]])
        assert sum(result[arm]["counts"].values()) == 2
    assert result["after"]["counts"]["whole"] == 2  # make repro's way never damages it
    # 130: DVC stopped; 0: the run ended first; -SIGINT: the Ctrl-C came while Python
    # was still starting the wrapper, or already ending it (DVC not running either way)
    assert all(run["exit"] in (0, 130, -signal.SIGINT) for run in result["after"]["runs"])
    table = render(result)
    for label in OUTCOMES.values():
        assert f"| {label} |" in table
    assert "python -m eskin.lockfile repro --force" in table
