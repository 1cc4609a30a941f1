"""make bench's lock_interrupts (harness/lock_interrupts.py) on a small DVC project of its
own: the stub it makes of a pipeline, how it tells a lock after a Ctrl-C, and both arms
on two Ctrl-Cs; and eskin's check (eskin/lockfile.py) on cuts of DVC's own write of the
project's lock, where the harness says a Ctrl-C can cut it."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from eskin.lockfile import lock_problem
from harness.lock_interrupts import (
    ARMS,
    OUTCOMES,
    dvc_write_boundaries,
    measure,
    outcome,
    render,
    stub_project,
)

ROOT = Path(__file__).resolve().parents[1]
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


@pytest.mark.starts
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


@pytest.mark.starts
def test_both_arms_on_the_same_seeded_ctrl_cs(root):
    result = measure(trials=2, seed=1, cuts=40, root=root, log=lambda line: None)
    for arm in ARMS:
        runs = result[arm]["runs"]
        assert [run["at"] / result[arm]["full_seconds"] for run in runs] == pytest.approx(
            [run["at"] / result["before"]["full_seconds"] for run in result["before"]["runs"]])
        assert sum(result[arm]["counts"].values()) == 2
    assert result["after"]["counts"]["whole"] == 2  # make repro's way never damages it
    # 130: DVC stopped; 0: the run ended first; -SIGINT: the Ctrl-C came while Python
    # was still starting the wrapper, or already ending it (DVC not running either way)
    exits = [run["exit"] for run in result["after"]["runs"]]
    assert all(code in (0, 130, -signal.SIGINT) for code in exits), exits  # which, if not
    cuts = result["cuts"]
    assert cuts["cuts"] == 40 and cuts["write_calls"] > 40
    assert cuts["dvc_rejects"] + cuts["eskin_only"] + cuts["untold"] == 40
    assert cuts["eskin_only"] > 0 and cuts["untold"] < 40 / 4
    table = render(result)
    for label in OUTCOMES.values():
        assert f"| {label} |" in table
    assert "python -m eskin.lockfile repro --force" in table


@pytest.fixture
def committed(tmp_path):
    """A git repository whose last commit holds the project's own dvc.lock."""
    (tmp_path / "dvc.lock").write_bytes((ROOT / "dvc.lock").read_bytes())
    for args in (["git", "init", "-q"], ["git", "add", "dvc.lock"], ["git", "commit", "-qm", "l"]):
        subprocess.run(args, cwd=tmp_path, env=ENV, check=True, capture_output=True, timeout=60)
    return tmp_path


@pytest.mark.heavy
def test_every_cut_of_dvcs_own_write_but_one_kind_is_told(committed):
    """Cuts of DVC's own write of the project's lock, at 100 of its 15,000 write
    boundaries: each is told, but for a cut at a line's end inside the last stage's
    entry (no stage after it to be missed). DVC's own loader and schema alone miss many
    of them: they are told by eskin's two marks of a cut."""
    text = (ROOT / "dvc.lock").read_text()
    last_stage = max(text.rindex(f"\n  {name}:\n") for name in yaml.safe_load(text)["stages"])
    lock = committed / "dvc.lock"
    told_by_marks = untold = 0
    for cut in sorted(random.Random(53).sample(dvc_write_boundaries(text), 100)):
        lock.write_text(text[:cut])
        told = lock_problem(lock)  # DVC's verdict first: the marks are for what it reads
        told_by_marks += told in ("is cut short: it ends mid-line",) or "are gone" in (told or "")
        if told is None:
            untold += 1
            assert text[:cut].endswith("\n") and cut > last_stage, (cut, text[cut - 60:cut])
    assert told_by_marks > 25  # a third or more of the cuts: DVC reads them without a word
    assert untold < 5
