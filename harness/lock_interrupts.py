"""Ctrl-C during `dvc repro` against dvc.lock (issue 53): how often an interrupt at a
random time leaves the lock damaged, under a plain ``dvc repro`` and under
``python -m eskin.lockfile repro`` (what ``make repro`` runs).

The project is a stub of the real one: its git-tracked files (dvc.yaml, params.yaml and
the code every stage lists as a dependency), every stage's command replaced by a stub
that writes the stage's outputs (a few bytes a file, one file in a directory output).
So its stages are the real ones, with the real dependencies, params and outputs, and
its lock the real lock's size (DVC's dump time depends on nothing else), while a stage
costs a Python start instead of minutes. The window a Ctrl-C can hit (DVC's write of
the whole lock, after every stage) is the real one; the stages between two windows
are shorter, so an interrupt at a random time lands in a window more often here than
in the real pipeline: an upper bound on it.

One ``dvc repro`` writes the reference lock; the stubs write the same bytes every
run, so a ``dvc repro --force`` that is interrupted leaves the reference lock where
the lock is whole (the stage it stopped has not been recorded; the ones before it
were recorded as they were). Then, for each of ``trials`` seeded times, uniform over
one uninterrupted ``dvc repro --force`` (timed here): the reference lock put back,
``dvc repro --force`` started in a process group of its own and SIGINT sent to that
group at that time, as a terminal's Ctrl-C is sent to its foreground group, and the lock
read once the command has exited. The same times for both ways of running DVC.

    PYTHONPATH=. python -m harness.lock_interrupts [--trials 20] [--seed 53] [--json FILE]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import random
import re
import shlex
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import yaml

from eskin.lockfile import LOCK, dvc_problem, lock_problem
from harness.repro_speed import ROOT, scratch_env, tracked_copy

TRIALS = 20
SEED = 53
# cuts of DVC's own write of the stub's lock, each read as DVC and as eskin read it
CUTS = 400
# The two ways of running DVC. A list that starts "dvc", "repro" would read, to
# tests/test_stage_deps.py, as running the project's pipeline; the stub runs none of it.
REPRO = ["repro", "--force"]
ARMS = {"before": ["dvc", *REPRO],
        "after": [sys.executable, "-m", "eskin.lockfile", *REPRO]}
ARM_LABELS = {"before": "plain `dvc repro --force`",
              "after": "`python -m eskin.lockfile repro --force` (make repro)"}
OUTCOMES = {"whole": "whole (the reference lock)",
            "empty": "missing or empty",
            "unreadable": "unparseable, or fails DVC's lockfile schema",
            "cut": "parses, but stages are missing or cut"}
RUNNING = re.compile(r"^Running stage '([^']+)'")
# DVC's record of which paths its running commands read and write: a small JSON file it
# rewrites in place, open("w") then json.dump, around every stage. A Ctrl-C in that
# write leaves it unreadable, and every DVC command then fails (treeverse/dvc#7615)
# until it is deleted. Counted beside the lock, and deleted before every run.
RWLOCK = Path(".dvc/tmp/rwlock")
STUB = '''"""A stage of the lock-interrupt stub project: writes its outputs, the same bytes
every run (harness/lock_interrupts.py)."""
import json, os, pathlib
stage = os.environ["DVC_STAGE"]
for path in json.loads(pathlib.Path("stub_outputs.json").read_text())[stage]:
    pathlib.Path(path).parent.mkdir(parents=True, exist_ok=True)
    pathlib.Path(path).write_text(f"{stage} {path}\\n")
'''


def stub_project(dest: Path, *, root: Path = ROOT) -> dict:
    """The stub project at ``dest`` (see the module's text), in a git repository of its
    own with its reference lock committed: what it is, beside the real lock."""
    from dvc.repo import Repo

    tracked_copy(dest, root=root)
    env = scratch_env(dest)
    subprocess.run(["git", "init", "-q"], cwd=dest, env=env, check=True, timeout=60)
    with Repo(str(dest)) as repo:  # the real lock says which outputs are directories
        stages = list(repo.index.stages)
        read = {os.path.relpath(dep.fs_path, dest) for stage in stages for dep in stage.deps}
        outputs = {stage.name: [(os.path.relpath(out.fs_path, dest),
                                 bool(out.hash_info and out.hash_info.isdir))
                                for out in stage.outs] for stage in stages}
    # a directory output: the files of it that other stages read, or one file
    files = {name: [file for path, is_dir in outs
                    for file in ((sorted(f for f in read if f.startswith(path + "/"))
                                  or [f"{path}/stub.txt"]) if is_dir else [path])]
             for name, outs in outputs.items()}
    pipeline = yaml.safe_load((dest / "dvc.yaml").read_text())
    for stage in pipeline["stages"].values():
        stage.get("do", stage)["cmd"] = "python stub.py"
    (dest / "dvc.yaml").write_text(yaml.safe_dump(pipeline, sort_keys=False))
    (dest / "stub.py").write_text(STUB)
    (dest / "stub_outputs.json").write_text(json.dumps(files, indent=1))
    real_bytes = (dest / LOCK).stat().st_size
    for args in (["git", "add", "-A"], ["git", "commit", "-qm", "stub"],
                 ["dvc", *REPRO[:1]], ["git", "add", LOCK],
                 ["git", "commit", "-qm", "the reference lock"]):
        subprocess.run(args, cwd=dest, env=env, check=True, capture_output=True, timeout=1800)
    return {"stages": len(outputs), "lock_bytes": (dest / LOCK).stat().st_size,
            "real_lock_bytes": real_bytes}


def dvc_write_boundaries(text: str) -> list[int]:
    """Where a Ctrl-C can cut DVC's write of a lock holding ``text``: after each write
    call of DVC's own dumper (a signal is handled between Python bytecodes, so a cut
    never falls inside one write)."""
    from dvc.utils.serialize._yaml import _dump, parse_yaml_for_update

    class Recording(io.StringIO):
        def __init__(self) -> None:
            super().__init__()
            self.ends: list[int] = []

        def write(self, data: str) -> int:
            written = super().write(data)
            self.ends.append(self.tell())
            return written

    stream = Recording()
    _dump(parse_yaml_for_update(text, LOCK), stream)
    if stream.getvalue() != text:
        raise ValueError("DVC's dumper does not write this lock back as it is")
    return [0, *stream.ends[:-1]]


def cut_census(lock: Path, *, cuts: int = CUTS, seed: int = SEED) -> dict:
    """``cuts`` seeded cuts of DVC's own write of the lock at ``lock`` (committed in git
    there, as the project's is), each told apart: DVC's own loader or schema rejects
    it; only eskin's check names it; or neither does."""
    text = lock.read_text()
    boundaries = dvc_write_boundaries(text)
    counts = dict.fromkeys(("dvc_rejects", "eskin_only", "untold"), 0)
    try:
        for cut in random.Random(seed).sample(boundaries, min(cuts, len(boundaries))):
            lock.write_text(text[:cut])
            counts["dvc_rejects" if dvc_problem(lock) else
                   "eskin_only" if lock_problem(lock) else "untold"] += 1
    finally:
        lock.write_text(text)
    return {"write_calls": len(boundaries), "cuts": sum(counts.values()), **counts}


def outcome(lock: Path, reference: dict) -> dict:
    """The lock after an interrupt, against the reference: its bytes, which of
    :data:`OUTCOMES` it is (DVC's own loader and schema tell "unreadable"), what
    :func:`eskin.lockfile.lock_problem` says of it, and a damaged one's last bytes."""
    if not lock.is_file() or lock.stat().st_size == 0:
        return {"bytes": lock.stat().st_size if lock.is_file() else None, "outcome": "empty",
                "problem": lock_problem(lock) if lock.is_file() else "missing", "ends": ""}
    text = lock.read_bytes()
    found = {"bytes": len(text), "problem": lock_problem(lock), "ends": text[-40:].decode(
        errors="replace")}
    if dvc_problem(lock):
        return {**found, "outcome": "unreadable"}
    stages = (yaml.safe_load(text) or {}).get("stages", {})
    wrong = sorted(name for name, entry in reference["stages"].items()
                   if stages.get(name) != entry)
    return {**found, "outcome": "cut" if wrong else "whole", "stages_wrong": len(wrong),
            **({} if wrong else {"ends": ""})}


def rwlock_whole(path: Path) -> bool:
    """Whether DVC can read its rwlock file at ``path`` (none at all: it makes one)."""
    try:
        json.loads(path.read_text())
    except FileNotFoundError:
        return True
    except ValueError:
        return False
    return True


def interrupted_run(project: Path, command: list[str], at: float, *, timeout: float) -> dict:
    """``command`` in ``project``, its process group sent SIGINT ``at`` seconds after it
    started; its exit code, the stage it was running, seconds from SIGINT to exit."""
    env = scratch_env(project)
    started = time.perf_counter()
    running = None
    with subprocess.Popen(command, cwd=project, env=env, stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True,
                          start_new_session=True) as proc:
        def ctrl_c() -> None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGINT)

        timer = threading.Timer(at, ctrl_c)
        timer.start()
        tail: list[str] = []
        try:
            for line in proc.stdout:  # type: ignore[union-attr]
                found = RUNNING.match(line)
                if found and time.perf_counter() - started < at:
                    running = found.group(1)
                tail = (tail + [line.rstrip()])[-8:]
            code = proc.wait(timeout=timeout)
        finally:
            timer.cancel()
            with contextlib.suppress(ProcessLookupError):  # the stub project's processes
                os.killpg(proc.pid, signal.SIGKILL)
        ended = time.perf_counter() - started
    return {"at": at, "exit": code, "stage": running,
            "seconds_to_exit": ended - at if ended >= at else None, "tail": tail}


def measure(*, trials: int = TRIALS, seed: int = SEED, cuts: int = CUTS, root: Path = ROOT,
            log=print) -> dict:
    """Both arms on the same ``trials`` seeded times (see the module's text)."""
    result: dict = {"trials": trials, "seed": seed, "cores": os.cpu_count(),
                    "load_average": {"start": os.getloadavg()[0]}}
    # A shell starts a background job (`&`) with SIGINT ignored, and a process started
    # with it ignored keeps it so (Python installs no handler): DVC would run on through
    # every Ctrl-C. Handled here, it is back to its default in the processes started.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        return _measure(result, trials=trials, seed=seed, cuts=cuts, root=root, log=log)
    finally:
        signal.signal(signal.SIGINT, previous)


def _measure(result: dict, *, trials: int, seed: int, cuts: int, root: Path, log) -> dict:
    with tempfile.TemporaryDirectory(prefix="eskin-lock-") as scratch:
        project = Path(scratch) / "project"
        log("the stub project: the real stages, a stub command each …")
        result["project"] = stub_project(project, root=root)
        reference_text = (project / LOCK).read_bytes()
        reference = yaml.safe_load(reference_text)
        log(f"  {result['project']['stages']} stages, lock {len(reference_text):,} bytes "
            f"(the real one {result['project']['real_lock_bytes']:,})")
        log(f"  {cuts} cuts of DVC's own write of the lock …")
        result["cuts"] = cut_census(project / LOCK, cuts=cuts, seed=seed)
        draw = random.Random(seed)
        shares = sorted(draw.random() for _ in range(trials))
        for arm, command in ARMS.items():
            # each arm's own uninterrupted run: the load on a shared machine moves
            # minutes apart, and a Ctrl-C after the end would test nothing
            (project / LOCK).write_bytes(reference_text)
            (project / RWLOCK).unlink(missing_ok=True)
            started = time.perf_counter()
            done = subprocess.run(command, cwd=project, env=scratch_env(project), text=True,
                                  stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                  timeout=1800)
            full = time.perf_counter() - started
            if done.returncode:
                raise RuntimeError(f"{shlex.join(command)} exited {done.returncode}:\n"
                                   + "\n".join(done.stdout.splitlines()[-10:]))
            log(f"  {arm}: uninterrupted, {full:.1f} s")
            runs = []
            for index, share in enumerate(shares):
                (project / LOCK).write_bytes(reference_text)
                (project / RWLOCK).unlink(missing_ok=True)  # DVC makes it anew
                run = interrupted_run(project, command, share * full, timeout=600)
                run.update(outcome(project / LOCK, reference),
                           rwlock_whole=rwlock_whole(project / RWLOCK))
                runs.append(run)
                log(f"  {arm} {index + 1:2d}/{trials}: Ctrl-C at {run['at']:5.1f} s in "
                    f"{run['stage'] or '(no stage yet)'}: {run['outcome']}, "
                    f"{run['bytes']} bytes, exit {run['exit']}"
                    + ("" if run["rwlock_whole"] else f", {RWLOCK} unreadable"))
            result[arm] = {"command": shlex.join(command[-3:] if arm == "after" else command),
                           "full_seconds": full, "runs": runs,
                           "finished_first": sum(r["seconds_to_exit"] is None for r in runs),
                           "rwlock_unreadable": sum(not r["rwlock_whole"] for r in runs),
                           "counts": {name: sum(r["outcome"] == name for r in runs)
                                      for name in OUTCOMES}}
            result["load_average"][f"after {arm}"] = os.getloadavg()[0]
    return result


def render(result: dict) -> str:
    project = result["project"]
    load = ", ".join(f"{when} {value:.1f}" for when, value in result["load_average"].items())
    lines = [f"{result['trials']} Ctrl-Cs at seeded random times (seed {result['seed']}), "
             "uniform over an uninterrupted run of the same command, in the stub project "
             f"(harness/lock_interrupts.py): the pipeline's {project['stages']} stages, a "
             f"stub command each, its lock {project['lock_bytes']:,} bytes (the real one "
             f"{project['real_lock_bytes']:,}). Load average (1 min) on {result['cores']} "
             f"cores: {load}.", "",
             "| the lock after the Ctrl-C | " + " | ".join(ARM_LABELS[a] for a in ARMS) + " |",
             "|---|" + "---|" * len(ARMS)]
    for name, label in OUTCOMES.items():
        lines.append(f"| {label} | " + " | ".join(
            f"{result[arm]['counts'][name]} of {result['trials']}" for arm in ARMS) + " |")
    lines.append(f"| and DVC's `{RWLOCK}` left unreadable (every DVC command fails) | "
                 + " | ".join(f"{result[arm]['rwlock_unreadable']} of {result['trials']}"
                              for arm in ARMS) + " |")
    for arm in ARMS:
        runs = result[arm]["runs"]
        damaged = [r for r in runs if r["outcome"] != "whole"]
        flagged = sum(bool(r["problem"]) for r in damaged)
        false_alarms = sum(bool(r["problem"]) for r in runs if r["outcome"] == "whole")
        waits = sorted(r["seconds_to_exit"] for r in runs if r["seconds_to_exit"] is not None)
        waits = waits or [float("nan")]
        lines += ["", f"{ARM_LABELS[arm]} (uninterrupted: {result[arm]['full_seconds']:.1f} s): "
                  f"{result[arm]['finished_first']} of {len(runs)} runs ended before their "
                  f"Ctrl-C; from Ctrl-C to exit {waits[0]:.1f}–{waits[-1]:.1f} s (median "
                  f"{waits[len(waits) // 2]:.1f} s). eskin's check (eskin/lockfile.py) names "
                  f"{flagged} of the {len(damaged)} damaged locks and "
                  f"{false_alarms} of the whole ones."]
        lines += [f"- {r['bytes']} bytes, {OUTCOMES[r['outcome']]}, ending "
                  f"`{r['ends'][-24:]!r}`: " + (r["problem"] or "not named") for r in damaged]
    cuts = result["cuts"]
    lines += ["", f"{cuts['cuts']} seeded cuts of DVC's own write of the lock (after "
              f"{cuts['cuts']} of its {cuts['write_calls']:,} write calls): DVC's loader or "
              f"schema rejects {cuts['dvc_rejects']}; of the rest, DVC reads without a word "
              f"and eskin's check names {cuts['eskin_only']}; named by neither: {cuts['untold']}."]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=TRIALS)
    parser.add_argument("--seed", type=int, default=SEED)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    result = measure(trials=args.trials, seed=args.seed,
                     log=lambda line: print(line, file=sys.stderr, flush=True))
    print(render(result))
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
