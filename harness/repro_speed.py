"""How long the default pipeline's `dvc repro` takes from an empty cache, against a
baseline revision's pipeline, both timed here, one after the other.

Each runs in a scratch copy: the project's files (the working tree's git-tracked files
for the current pipeline, ``git archive <revision>`` for the baseline), a fresh git
repository, no DVC cache and an MLflow store of its own (SQLite), and ``dvc repro --force``,
so every stage runs: acquisition, training, scoring, export and the report (without
--force, a stage whose outputs are all in git, as the pairs scores are, and whose inputs
came out the same is skipped, in one copy and not the other). A stage's time runs from DVC's
"Running stage" line to the next stage's (or to the end). The ratio is the current
pipeline's total over the baseline's: the same machine, the same load, minutes apart.

    PYTHONPATH=. python -m harness.repro_speed <baseline revision> [--json FILE]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tarfile
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RUNNING = re.compile(r"^Running stage '([^']+)'")
TARGET_SECONDS = 60.0  # issue 21, item 10


def tracked_copy(dest: Path, revision: str | None = None, *, root: Path = ROOT) -> None:
    """The project as git has it: ``revision``'s tree, or (None) the working tree's
    tracked files, edits included; untracked and ignored files (data, caches) left out."""
    dest.mkdir(parents=True, exist_ok=True)
    if revision is not None:
        archive = subprocess.run(["git", "archive", "--format=tar", revision], cwd=root,
                                 capture_output=True, check=True, timeout=120).stdout
        with tempfile.TemporaryFile() as tar_file:
            tar_file.write(archive)
            tar_file.seek(0)
            with tarfile.open(fileobj=tar_file) as tar:
                tar.extractall(dest, filter="data")
        return
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=root, capture_output=True,
                            check=True, timeout=60).stdout.decode().split("\0")
    for name in filter(None, listed):
        source = root / name
        if source.is_file():  # a tracked file deleted in the working tree is left out
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, dest / name)


def scratch_env(project: Path) -> dict[str, str]:
    """The environment a user's `dvc repro` has, with the project's own MLflow store;
    none of the calling DVC stage's variables."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("DVC_", "MLFLOW_"))}
    bin_dir = str(Path(sys.executable).parent)  # dvc, and the python DVC's stages call
    return {**env, "PATH": f"{bin_dir}{os.pathsep}{env.get('PATH', '')}",
            "DVC_NO_ANALYTICS": "1", "MLFLOW_ENABLE_TELEMETRY": "false", "DO_NOT_TRACK": "1",
            "MLFLOW_TRACKING_URI": f"sqlite:///{project / 'mlflow.db'}",
            "GIT_AUTHOR_NAME": "bench", "GIT_AUTHOR_EMAIL": "bench@localhost",
            "GIT_COMMITTER_NAME": "bench", "GIT_COMMITTER_EMAIL": "bench@localhost"}


def timed_repro(project: Path, *, timeout: float, log=print) -> dict:
    """`dvc repro --force` in ``project`` (committed to a fresh git repository first, as a
    clone is): total seconds and each stage's, from DVC's own output."""
    env = scratch_env(project)
    for args in (["git", "init", "-q"], ["git", "add", "-A"], ["git", "commit", "-qm", "copy"]):
        subprocess.run(args, cwd=project, env=env, check=True, capture_output=True, timeout=120)
    started = time.perf_counter()
    marks: list[tuple[str, float]] = []
    tail: list[str] = []
    # its own process group: at the deadline, DVC and the stage it runs are killed together
    # (the stage holds the output pipe open)
    with subprocess.Popen(["dvc", "repro", "--force"], cwd=project, env=env, stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True, start_new_session=True) as proc:
        def kill() -> None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)

        deadline = threading.Timer(timeout, kill)  # a stage that hangs, silent
        deadline.start()
        try:
            for line in proc.stdout:  # type: ignore[union-attr]
                found = RUNNING.match(line)
                if found:
                    marks.append((found.group(1), time.perf_counter() - started))
                    log(f"  {marks[-1][1]:6.1f} s  {found.group(1)}")
                tail = (tail + [line.rstrip()])[-20:]
        finally:
            deadline.cancel()
            if proc.poll() is None:
                kill()
        code = proc.wait(timeout=60)
    total = time.perf_counter() - started
    if total >= timeout:
        raise TimeoutError(f"{project}: dvc repro still running after {timeout:.0f} s; killed")
    if code != 0:
        raise RuntimeError(f"{project}: dvc repro exited {code}:\n" + "\n".join(tail))
    ends = [t for _, t in marks[1:]] + [total]
    return {"seconds": total,
            "stages": {name: end - start for (name, start), end in zip(marks, ends, strict=True)}}


def measure(baseline: str, *, timeout: float = 1800, root: Path = ROOT, log=print) -> dict:
    """The baseline revision's pipeline, then the working tree's, each from scratch."""
    commit = subprocess.run(["git", "rev-parse", "--verify", f"{baseline}^{{commit}}"],
                            cwd=root, capture_output=True, text=True, timeout=30)
    if commit.returncode != 0:
        raise ValueError(f"bench.repro_baseline: {baseline!r} is not a commit of this "
                         "repository (a shallow clone lacks history: git fetch --unshallow)")
    result: dict = {"target_seconds": TARGET_SECONDS}
    with tempfile.TemporaryDirectory(prefix="eskin-repro-") as scratch:
        for name, revision in (("baseline", commit.stdout.strip()), ("current", None)):
            project = Path(scratch) / name
            tracked_copy(project, revision, root=root)
            log(f"{name} ({revision or 'working tree'}): dvc repro from an empty cache …")
            result[name] = {"revision": revision or "working tree",
                            **timed_repro(project, timeout=timeout, log=log)}
    result["ratio"] = result["current"]["seconds"] / result["baseline"]["seconds"]
    result["met"] = result["current"]["seconds"] < TARGET_SECONDS
    return result


def render(result: dict) -> str:
    base, current = result["baseline"], result["current"]
    names = list(dict.fromkeys([*current["stages"], *base["stages"]]))
    lines = [f"The default pipeline's `dvc repro --force` from an empty cache: "
             f"**{current['seconds']:.0f} s**, {result['ratio']:.2f}× the baseline "
             f"({base['revision'][:7]}: {base['seconds']:.0f} s), run just before it; "
             f"target under {result['target_seconds']:.0f} s: "
             f"{'met' if result['met'] else 'MISSED'}.", "",
             "| stage | baseline | current |", "|---|---|---|"]

    def seconds(run: dict, name: str) -> str:
        return f"{run['stages'][name]:.1f} s" if name in run["stages"] else "—"

    lines += [f"| {name} | {seconds(base, name)} | {seconds(current, name)} |" for name in names]
    lines.append(f"| **total** | **{base['seconds']:.1f} s** | **{current['seconds']:.1f} s** |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("baseline")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    result = measure(args.baseline)
    print(render(result))
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
