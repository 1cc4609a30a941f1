"""dvc.lock through a Ctrl-C (issue 53).

DVC rewrites the whole lock in place after every stage: it opens ``dvc.lock`` with
``"w+"`` (which empties it) and then streams ruamel's YAML into it
(``dvc.utils.serialize._common._dump_data``; the same in DVC 3.67.1, the newest
release, and on its main branch). A Ctrl-C that lands in that write raises
KeyboardInterrupt inside the dump and leaves the lock cut short: empty (every DVC
command then fails, "validation failed"), or a prefix that still parses (``dvc
status`` then calls every stage after the cut changed).

Two layers here:

- :func:`run_dvc` (``python -m eskin.lockfile repro ...``, what ``make repro`` runs):
  DVC in a session of its own, so a terminal's Ctrl-C reaches this process and not
  DVC; it goes on to the processes of the stage DVC is running (or, between stages,
  of the next one it starts). The stage fails, and DVC stops through its own error
  path, having written the lock for every stage that finished. A second Ctrl-C goes to
  DVC too, as a plain ``dvc repro`` would have it.
- :func:`check_lock` (every ``eskin`` command but those that need no project, and
  :func:`run_dvc` before and after DVC): a lock that DVC's own loader or lockfile schema
  rejects, or that bears a mark of a cut DVC reads without a word, told in one line
  with the way back; read again under DVC's repository lock first, so that a lock DVC
  is writing at that moment is not called damaged.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

from eskin.errors import STOPPED, EskinError, run_friendly

LOCK = "dvc.lock"
# How often a pending Ctrl-C looks for the stage to stop: DVC starts the next stage's
# process after hashing the last one's outputs and writing the lock, seconds later.
POLL_S = 0.05
EXIT_INTERRUPTED = 130  # 128 + SIGINT, as a shell reports a command Ctrl-C stopped


def dvc_problem(path: Path) -> str | None:
    """What DVC's own loader and lockfile schema find wrong with the lock file at
    ``path`` (what makes every DVC command fail), or None."""
    from dvc.dvcfile import Lockfile
    from dvc.exceptions import DvcException
    from dvc.utils.strictyaml import YAMLSyntaxError, YAMLValidationError, load

    if not path.read_bytes().strip():
        return "is empty"
    try:
        load(str(path), Lockfile.SCHEMA)
    except YAMLSyntaxError:
        return "is cut short: DVC cannot parse it"
    except YAMLValidationError:
        return "fails DVC's lockfile schema"
    except DvcException as err:  # not UTF-8
        return f"cannot be read by DVC ({err})"
    return None


def lock_problem(path: Path) -> str | None:
    """What is wrong with the lock file at ``path``, or None: :func:`dvc_problem`, then
    two marks of a write cut short that DVC cannot see. A cut mid-line still parses
    and passes DVC's schema (a hash cut short is still a string): it is told by its
    last line, which DVC's dumper always ends. A cut at a line's end, by the stages
    after it that are gone, as the last commit's lock names them, and dvc.yaml still
    does (DVC adds and rewrites a lock's stages, never drops one; a stage gone from
    dvc.yaml may be taken out of the lock by hand, or by `dvc remove`)."""
    import yaml

    problem = dvc_problem(path)
    if problem:
        return problem
    text = path.read_bytes()
    if not text.endswith(b"\n"):
        return "is cut short: it ends mid-line"
    lost = sorted(committed_stages(path) - set(yaml.load(text, Loader=yaml.CSafeLoader)
                                               .get("stages") or {}))
    if lost:  # rare: only then is the pipeline read, for a stage since removed from it
        defined = pipeline_stages(path)
        lost = [name for name in lost if defined is None or name in defined]
    if lost:
        return (f"is cut short: {len(lost)} of the stages the last commit's {path.name} "
                f"records are gone ({', '.join(lost[:2])}{', ...' if len(lost) > 2 else ''})")
    return None


def pipeline_stages(path: Path) -> set[str] | None:
    """The stages the dvc.yaml beside the lock file at ``path`` defines, as DVC names them
    (``train@single_force``); None where DVC cannot read it."""
    from dvc.dvcfile import load_file
    from dvc.exceptions import DvcException
    from dvc.repo import Repo

    try:
        with Repo(str(path.parent), uninitialized=True) as repo:
            return set(load_file(repo, str(path.with_name("dvc.yaml"))).stages.keys())
    except (DvcException, OSError):
        return None


def committed_stages(path: Path) -> set[str]:
    """The stages the lock file at ``path`` records in git's HEAD (none where git, a
    commit or that file is missing)."""
    import yaml

    try:
        shown = subprocess.run(["git", "show", f"HEAD:./{path.name}"], cwd=path.parent,
                               capture_output=True, timeout=30)
    except (OSError, subprocess.SubprocessError):
        return set()
    try:  # pyyaml's C loader: the names only, in a tenth of DVC's time
        committed = yaml.load(shown.stdout, Loader=yaml.CSafeLoader) if not shown.returncode \
            else None
    except yaml.YAMLError:
        return set()
    stages = committed.get("stages") if isinstance(committed, dict) else None
    return set(stages) if isinstance(stages, dict) else set()


def check_lock(root: Path = Path()) -> None:
    """Refuse, in one line, a ``dvc.lock`` under ``root`` that :func:`lock_problem`
    finds damaged. None at all is fine: a project before its first ``dvc repro`` has
    none."""
    path = root / LOCK
    if not path.is_file():
        return
    problem = lock_problem(path) and _problem_once_dvc_is_done(root, path)
    if not problem:
        return
    # DVC's run cache restores a stage only where all its outputs are cached: here
    # ingest, featurize and folds; training, scoring and the report run again
    # (measured on the stub project of harness/lock_interrupts.py, docs/getting-started.md)
    restore = (f"restore the last committed one with `git checkout {path}`, then run `dvc "
               "repro`, which reruns the stages changed since that commit"
               if committed_stages(path) else
               "delete it (git has none to restore), then run `dvc repro`, which reruns "
               "every stage")
    raise EskinError(f"{path} {problem} (a Ctrl-C during `dvc repro`?): {restore} (those "
                     "whose outputs are all in DVC's cache come back from it instead)")


def _problem_once_dvc_is_done(root: Path, path: Path) -> str | None:
    """:func:`lock_problem` again, holding DVC's repository lock (waiting for it as a DVC
    command does): a DVC command of this project may be writing the lock right now (it
    holds that lock from a stage's end until the stage is recorded)."""
    from dvc.exceptions import NotDvcRepoError
    from dvc.lock import LockError
    from dvc.repo import Repo

    try:
        with Repo(str(root)) as repo, repo.lock:
            return lock_problem(path)
    except NotDvcRepoError:
        return lock_problem(path)
    except LockError as err:
        raise EskinError(f"DVC is running in {root.resolve()} and may be writing {path} "
                         "(.dvc/tmp/lock is held): try again once it is done") from err


# Commands that work without a project (a board on a port, the simulated skin, a
# running live view), so without a lock: every other command reads the pipeline's
# files or writes what its next `dvc repro` reads, and that repro fails on a lock DVC
# cannot read, or reruns the stages after a cut.
NO_PIPELINE = ("ports", "device", "press")


def checked(command: str, run):
    """The function of eskin command ``command``, run after :func:`check_lock` unless the
    command works without a project."""
    def run_checked(args):
        if command not in NO_PIPELINE:
            check_lock()
        return run(args)
    return run_checked


def _interrupt_new_stages(dvc_pid: int, stopped: set) -> None:
    """SIGINT to each process DVC has started since the last call (a stage's shell or
    command), and to everything under it, as a terminal's Ctrl-C would reach them;
    ``stopped`` holds the ones already sent it. What a stopped stage starts while it
    winds down is left alone, as a terminal would leave it."""
    import psutil

    try:
        started = set(psutil.Process(dvc_pid).children())
    except psutil.Error:  # DVC has just exited
        return
    for stage in started - stopped:
        with contextlib.suppress(psutil.Error):
            for process in [stage, *stage.children(recursive=True)]:
                with contextlib.suppress(psutil.Error):
                    process.send_signal(signal.SIGINT)
        stopped.add(stage)


def run_dvc(args: Sequence[str], *, cwd: Path | None = None,
            note=lambda line: print(line, file=sys.stderr, flush=True)) -> int:
    """``dvc <args>`` in ``cwd`` with Ctrl-C routed to DVC's stage (see the module's
    text): DVC's exit code, or 130 after a Ctrl-C."""
    check_lock(cwd or Path())
    presses: list[int] = []

    def pressed(signum, frame) -> None:
        presses.append(signum)

    # before DVC starts: a Ctrl-C from then on is counted, never a KeyboardInterrupt
    # here that would leave DVC running on its own
    previous = {signal.SIGINT: signal.signal(signal.SIGINT, pressed)}
    try:
        dvc = subprocess.Popen(["dvc", *args], cwd=cwd, start_new_session=True)

        def forward(signum, frame) -> None:  # a hangup, Ctrl-\ or kill: DVC's as well
            with contextlib.suppress(ProcessLookupError):
                os.killpg(dvc.pid, signum)

        def suspend(signum, frame) -> None:
            # Ctrl-Z: DVC and its stage stop with this process, and go on with it. Its
            # session has no terminal, so the kernel would drop a SIGTSTP sent to it.
            with contextlib.suppress(ProcessLookupError):
                os.killpg(dvc.pid, signal.SIGSTOP)
            signal.signal(signal.SIGTSTP, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGTSTP)  # stops here until `fg` or `bg`
            signal.signal(signal.SIGTSTP, suspend)
            with contextlib.suppress(ProcessLookupError):
                os.killpg(dvc.pid, signal.SIGCONT)

        for signum in (signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT):
            previous[signum] = signal.signal(signum, forward)
        previous[signal.SIGTSTP] = signal.signal(signal.SIGTSTP, suspend)
        stopped: set = set()
        told = 0
        while True:
            with contextlib.suppress(subprocess.TimeoutExpired):
                code = dvc.wait(timeout=POLL_S)
                break
            if presses and not told:
                note("eskin: Ctrl-C: stopping the stage DVC is running, so that DVC stops "
                     f"with {LOCK} whole (Ctrl-C again stops DVC at once, which can cut "
                     f"{LOCK} short)")
                told = 1
            if len(presses) > 1 and told == 1:
                note(f"eskin: Ctrl-C again: stopping DVC at once; {LOCK} may be cut short")
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(dvc.pid, signal.SIGINT)
                told = 2
            if presses:
                _interrupt_new_stages(dvc.pid, stopped)
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    if not presses:
        return code
    check_lock(cwd or Path())
    note(f"eskin: interrupted; {LOCK} is whole: it records every stage that finished")
    return EXIT_INTERRUPTED


def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help"):
        print("usage: python -m eskin.lockfile DVC_COMMAND [ARGS...]  (e.g. repro, "
              "exp run -S knob=1)\n" + __doc__.split("\n\n")[0])
        return 0 if args else 2
    return run_friendly(lambda: run_dvc(args), interrupted=STOPPED)


if __name__ == "__main__":
    sys.exit(main())
