"""make bench's repro_speed (harness/repro_speed.py) on a small DVC project of its own:
a baseline commit and a working tree whose stages sleep for known times."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from harness.repro_speed import measure, render, timed_repro, tracked_copy

STAGE = """  {name}:
    cmd: python -c "import time; time.sleep({seconds}); open('{name}.txt', 'w').write('x')"
    outs: [{name}.txt]
"""


def pipeline(root: Path, sleeps: dict[str, float]) -> None:
    (root / "dvc.yaml").write_text("stages:\n" + "".join(
        STAGE.format(name=name, seconds=seconds) for name, seconds in sleeps.items()))


@pytest.fixture
def project(tmp_path):
    root = tmp_path / "project"
    root.mkdir()
    env = {"GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@t", "GIT_COMMITTER_NAME": "t",
           "GIT_COMMITTER_EMAIL": "t@t", "PATH": f"{Path(sys.executable).parent}:/usr/bin:/bin",
           "DVC_NO_ANALYTICS": "1"}
    pipeline(root, {"slow_start": 0.2, "middle": 1.0})
    for args in (["git", "init", "-q"], ["dvc", "init", "-q"], ["git", "add", "-A"],
                 ["git", "commit", "-qm", "baseline"]):
        subprocess.run(args, cwd=root, env=env, check=True, capture_output=True)
    baseline = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True,
                              text=True, check=True).stdout.strip()
    # the working tree, uncommitted: the middle stage slower, a stage more
    pipeline(root, {"slow_start": 0.2, "middle": 2.0, "added": 0.2})
    (root / "untracked.txt").write_text("not copied")
    return root, baseline


def test_the_working_tree_is_timed_against_the_baseline_commit_stage_by_stage(project):
    root, baseline = project
    result = measure(baseline, root=root, log=lambda line: None)
    base, current = result["baseline"], result["current"]
    assert list(base["stages"]) == ["slow_start", "middle"]
    assert list(current["stages"]) == ["slow_start", "middle", "added"]
    assert 1.0 <= base["stages"]["middle"] < current["stages"]["middle"]
    assert current["stages"]["middle"] >= 2.0
    assert sum(current["stages"].values()) <= current["seconds"]
    assert result["ratio"] == pytest.approx(current["seconds"] / base["seconds"])
    assert result["ratio"] > 1 and result["met"] is True  # a few seconds: under 60
    table = render(result)
    assert f"{result['ratio']:.2f}× the baseline ({baseline[:7]}" in table
    assert "| added | — |" in table and "| **total** |" in table


def test_the_copy_holds_the_tracked_files_as_edited_and_nothing_untracked(project, tmp_path):
    root, baseline = project
    tracked_copy(tmp_path / "now", root=root)
    tracked_copy(tmp_path / "then", baseline, root=root)
    assert "added" in (tmp_path / "now" / "dvc.yaml").read_text()
    assert "added" not in (tmp_path / "then" / "dvc.yaml").read_text()
    assert not (tmp_path / "now" / "untracked.txt").exists()
    assert (tmp_path / "then" / ".dvc" / "config").exists()


def test_a_revision_that_is_not_a_commit_is_one_clear_error(project):
    root, _ = project
    with pytest.raises(ValueError, match="bench.repro_baseline: 'deadbeef' is not a commit"):
        measure("deadbeef", root=root, log=lambda line: None)


def test_a_stage_that_hangs_is_killed_at_the_deadline(project, tmp_path):
    root, _ = project
    copy = tmp_path / "hang"
    tracked_copy(copy, root=root)
    pipeline(copy, {"hangs": 120})
    started = time.perf_counter()
    with pytest.raises(TimeoutError, match="still running after 3 s"):
        timed_repro(copy, timeout=3, log=lambda line: None)
    assert time.perf_counter() - started < 30


def test_a_failing_pipeline_says_so_with_dvc_s_last_lines(project, tmp_path):
    root, _ = project
    copy = tmp_path / "fails"
    tracked_copy(copy, root=root)
    (copy / "dvc.yaml").write_text(
        "stages:\n  broken:\n    cmd: python -c \"raise SystemExit(3)\"\n")
    with pytest.raises(RuntimeError, match="dvc repro exited") as caught:
        timed_repro(copy, timeout=60, log=lambda line: None)
    assert "broken" in str(caught.value)
