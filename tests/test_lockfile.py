"""dvc.lock through a Ctrl-C (eskin/lockfile.py, issue 53): a damaged lock told in one
line by every command that works on the pipeline (every cut of DVC's own write of the
lock: tests/test_lock_interrupts.py); and DVC run so that a Ctrl-C stops the stage, not
the write: real DVC, real signals, under make as `make repro` runs it."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest
import yaml

from eskin import cli
from eskin.errors import EskinError
from eskin.lockfile import check_lock, dvc_problem, lock_problem

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@t",
       "GIT_COMMITTER_NAME": "t", "GIT_COMMITTER_EMAIL": "t@t", "DVC_NO_ANALYTICS": "1",
       "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}


def run(args: list[str], cwd: Path) -> None:
    subprocess.run(args, cwd=cwd, env=ENV, check=True, capture_output=True, timeout=120)


@pytest.fixture
def committed(tmp_path):
    """A git repository whose last commit holds the project's own dvc.lock, beside its
    dvc.yaml and params.yaml (which the stages' names come from)."""
    for name in ("dvc.lock", "dvc.yaml", "params.yaml"):
        (tmp_path / name).write_bytes((ROOT / name).read_bytes())
    for args in (["git", "init", "-q"], ["git", "add", "dvc.lock"], ["git", "commit", "-qm", "l"]):
        run(args, tmp_path)
    return tmp_path


def test_a_whole_lock_passes(committed):
    assert lock_problem(committed / "dvc.lock") is None
    check_lock(committed)


def test_an_empty_lock_is_told_in_one_line_with_the_way_back(committed, monkeypatch):
    from dvc.dvcfile import Lockfile
    from dvc.utils.strictyaml import YAMLValidationError, load

    (committed / "dvc.lock").write_bytes(b"")
    with pytest.raises(YAMLValidationError):  # what makes every DVC command fail
        load(str(committed / "dvc.lock"), Lockfile.SCHEMA)
    monkeypatch.chdir(committed)
    with pytest.raises(EskinError) as told:
        check_lock()
    message = str(told.value)
    assert "\n" not in message
    assert message.startswith("dvc.lock is empty (a Ctrl-C during `dvc repro`?)")
    assert "`git checkout dvc.lock`, then run `dvc repro`" in message
    # where git has no lock to restore, the way back is another
    run(["git", "rm", "-q", "--cached", "dvc.lock"], committed)
    run(["git", "commit", "-qm", "none"], committed)
    with pytest.raises(EskinError, match=r"delete it \(git has none to restore\)"):
        check_lock()


def test_a_cut_at_a_line_end_is_told_by_the_stages_gone(committed):
    text = (ROOT / "dvc.lock").read_text()
    first, second = list(yaml.safe_load(text)["stages"])[:2]
    (committed / "dvc.lock").write_text(text[:text.index(f"\n  {second}:\n") + 1])
    stages = len(yaml.safe_load(text)["stages"])
    assert dvc_problem(committed / "dvc.lock") is None  # DVC reads it: 1 stage of them all
    assert lock_problem(committed / "dvc.lock") == (
        f"is cut short: {stages - 1} of the stages the last commit's dvc.lock records are gone "
        f"({', '.join(sorted(set(yaml.safe_load(text)['stages']) - {first})[:2])}, ...)")


def test_a_stage_removed_from_dvc_yaml_and_from_the_lock_is_no_cut(committed):
    """DVC never drops a stage from the lock; one taken out by hand, after it left
    dvc.yaml (a stage renamed, a scene removed), is no sign of a cut. The same lock,
    cut there while dvc.yaml still defines the stage, is."""
    text = (ROOT / "dvc.lock").read_text()
    document = yaml.safe_load(text)
    gone = "train@two_force"
    assert gone in document["stages"]
    del document["stages"][gone]
    (committed / "dvc.lock").write_text(yaml.safe_dump(document, sort_keys=False))
    assert lock_problem(committed / "dvc.lock").startswith("is cut short: 1 of the stages")
    pipeline = yaml.safe_load((committed / "dvc.yaml").read_text())
    pipeline["stages"]["train"]["foreach"] = ["single_force"]
    (committed / "dvc.yaml").write_text(yaml.safe_dump(pipeline, sort_keys=False))
    assert lock_problem(committed / "dvc.lock") is None


def test_commands_on_the_pipeline_refuse_a_damaged_lock_the_device_tools_do_not(
        committed, monkeypatch, capsys):
    text = (ROOT / "dvc.lock").read_text()  # cut mid-hash: DVC still reads it (lock_problem)
    (committed / "dvc.lock").write_text(text[:text.index("md5: ", 8000) + len("md5: ") + 10])
    monkeypatch.chdir(committed)
    assert cli.main(["audit"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith("eskin: error: dvc.lock is cut short: it ends mid-line")
    assert cli.main(["ports"]) == 0
    assert "dvc.lock" not in capsys.readouterr().err
    cli.main(["press", "--release", "--view", "1"])  # no live view there: its own error
    assert "dvc.lock" not in capsys.readouterr().err


@pytest.mark.starts
def test_a_lock_dvc_is_writing_waits_for_dvc(committed):
    """While a DVC command holds the project's lock (as from a stage's end until it is
    recorded), a lock cut short may be half written: read again once DVC is done; told
    as DVC at work, not as damage, if it takes longer than DVC itself waits."""
    run(["dvc", "init", "-q"], committed)
    whole = (committed / "dvc.lock").read_bytes()
    (committed / "dvc.lock").write_bytes(whole[:1000])
    holder = """import sys, time
from pathlib import Path
from dvc.lock import make_lock
lock = make_lock(".dvc/tmp/lock")
lock.lock()
print("held", flush=True)
time.sleep(float(sys.argv[1]))
Path("dvc.lock").write_bytes(Path(sys.argv[2]).read_bytes())
lock.unlock()
"""
    (committed / "whole.lock").write_bytes(whole)
    for hold, outcome in ((1.0, None), (30.0, "DVC is running")):
        (committed / "dvc.lock").write_bytes(whole[:1000])
        with subprocess.Popen([sys.executable, "-c", holder, str(hold), "whole.lock"],
                              cwd=committed, env=ENV, stdout=subprocess.PIPE, text=True) as dvc:
            assert dvc.stdout.readline() == "held\n"
            if outcome is None:
                check_lock(committed)  # waited, then read the whole lock
            else:
                with pytest.raises(EskinError, match=outcome):
                    check_lock(committed)
            dvc.kill()


PIPELINE = """stages:
  first:
    cmd: python stage.py first 2
    deps: [stage.py]
    outs: [first.txt]
  second:
    cmd: python stage.py second 60
    deps: [stage.py, first.txt]
    outs: [second.txt]
"""
# a stage: notes its process and its parent (DVC), works for a while, writes its output;
# STUBBORN set, it notes each SIGINT and gives in at the second
STAGE = """import os, signal, sys, time
from pathlib import Path
name, seconds = sys.argv[1], float(sys.argv[2])
def noted(signum, frame):
    with open(f"{name}.signals", "a") as log:
        log.write("INT\\n")
    if len(Path(f"{name}.signals").read_text().split()) > 1:
        sys.exit(130)
if os.environ.get("STUBBORN"):
    signal.signal(signal.SIGINT, noted)
Path(f"{name}.started").write_text(f"{os.getpid()} {os.getppid()}")
time.sleep(seconds)
Path(f"{name}.txt").write_text(name)
"""


@pytest.fixture
def pipeline(tmp_path):
    (tmp_path / "dvc.yaml").write_text(PIPELINE)
    (tmp_path / "stage.py").write_text(STAGE)
    (tmp_path / "Makefile").write_text("repro:\n\tpython -m eskin.lockfile repro\n")
    for args in (["git", "init", "-q"], ["dvc", "init", "-q"], ["git", "add", "-A"],
                 ["git", "commit", "-qm", "p"]):
        run(args, tmp_path)
    return tmp_path


def wait_for(path: Path, timeout: float = 60) -> list[int]:
    deadline = time.monotonic() + timeout
    while not path.is_file() or not path.read_text():
        assert time.monotonic() < deadline, f"{path.name} never appeared"
        time.sleep(0.05)
    return [int(word) for word in path.read_text().split()]


def gone(pid: int, timeout: float = 10) -> bool:
    """Whether process ``pid`` has ended (a zombie has), waiting up to ``timeout``."""
    try:
        psutil.Process(pid).wait(timeout=timeout)
    except psutil.TimeoutExpired:
        return False
    except psutil.NoSuchProcess:  # not a child of this process: it waits on nothing
        pass
    return not psutil.pid_exists(pid) or psutil.Process(pid).status() == psutil.STATUS_ZOMBIE


@pytest.mark.starts
def test_ctrl_c_under_make_stops_the_stage_and_dvc_records_the_stages_before(pipeline):
    """`make repro`'s way, Ctrl-C as a terminal sends it: SIGINT to the foreground process
    group (make and the wrapper; DVC runs in a session of its own)."""
    with subprocess.Popen(["make", "--no-print-directory", "repro"], cwd=pipeline, env=ENV,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                          start_new_session=True) as make:
        stage, dvc = wait_for(pipeline / "second.started")
        os.killpg(make.pid, signal.SIGINT)
        output, _ = make.communicate(timeout=60)
    assert make.returncode != 0
    assert gone(stage) and gone(dvc)
    assert "eskin: Ctrl-C: stopping the stage DVC is running" in output
    assert "eskin: interrupted; dvc.lock is whole" in output
    assert lock_problem(pipeline / "dvc.lock") is None
    recorded = yaml.safe_load((pipeline / "dvc.lock").read_text())["stages"]
    assert list(recorded) == ["first"]
    assert not (pipeline / "second.txt").exists()


def test_a_ctrl_c_before_any_stage_stops_the_first_one_dvc_starts(pipeline):
    started = time.monotonic()
    with subprocess.Popen([sys.executable, "-m", "eskin.lockfile", "repro"], cwd=pipeline,
                          env=ENV, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                          text=True, start_new_session=True) as wrapper:
        def dvc_started() -> bool:  # its own program in its own session, still importing
            return any(any("dvc" in word for word in child.cmdline())
                       for child in psutil.Process(wrapper.pid).children())

        while not dvc_started():
            time.sleep(0.01)
        os.killpg(wrapper.pid, signal.SIGINT)
        output, _ = wrapper.communicate(timeout=60)
    assert wrapper.returncode == 130, output
    # DVC started the first stage, which was stopped (at once: before it wrote a byte),
    # and DVC stopped through its own error path, the second never started
    assert "Running stage 'first'" in output and "ERROR: failed to reproduce 'first'" in output
    assert "Running stage 'second'" not in output
    assert not (pipeline / "first.txt").exists()
    assert time.monotonic() - started < 30
    assert not (pipeline / "dvc.lock").exists()  # nothing finished, nothing recorded


@pytest.mark.starts
def test_ctrl_z_stops_dvc_and_its_stage_and_a_kill_reaches_them(pipeline):
    # a process group in the test's session, as a shell's job is in the terminal's
    with subprocess.Popen([sys.executable, "-m", "eskin.lockfile", "repro"], cwd=pipeline,
                          env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                          process_group=0) as wrapper:
        stage, dvc = wait_for(pipeline / "second.started")
        processes = [psutil.Process(pid) for pid in (wrapper.pid, dvc, stage)]
        os.killpg(wrapper.pid, signal.SIGTSTP)
        time.sleep(1)
        assert [p.status() for p in processes] == [psutil.STATUS_STOPPED] * 3
        os.killpg(wrapper.pid, signal.SIGCONT)
        time.sleep(1)
        assert psutil.STATUS_STOPPED not in [p.status() for p in processes]
        wrapper.terminate()
        wrapper.wait(timeout=30)
    assert gone(stage) and gone(dvc)


@pytest.mark.starts
def test_a_second_ctrl_c_reaches_dvc_and_its_stage_as_a_plain_one_would(pipeline):
    """A stage that holds out against the first Ctrl-C (the wrapper's, to the stage
    alone): the second is sent to DVC's whole process group, and the stage gives in."""
    with subprocess.Popen([sys.executable, "-m", "eskin.lockfile", "repro"], cwd=pipeline,
                          env={**ENV, "STUBBORN": "1"}, stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True,
                          start_new_session=True) as wrapper:
        stage, dvc = wait_for(pipeline / "second.started")
        os.killpg(wrapper.pid, signal.SIGINT)
        while not (pipeline / "second.signals").is_file():
            time.sleep(0.05)
        time.sleep(1)
        assert wrapper.poll() is None and not gone(stage, timeout=0)  # held out
        os.killpg(wrapper.pid, signal.SIGINT)
        output, _ = wrapper.communicate(timeout=60)
    assert (pipeline / "second.signals").read_text() == "INT\nINT\n"
    assert "eskin: Ctrl-C again: stopping DVC at once" in output
    assert gone(stage) and gone(dvc)
    assert list(yaml.safe_load((pipeline / "dvc.lock").read_text())["stages"]) == ["first"]
