"""Errors a user can act on, and how a command reports them: one line, exit code 1.

Every stage and the ``eskin`` command run through :func:`run_friendly`. It
imports nothing of eskin's own, so a stage depends (in dvc.yaml) only on the
code it runs, not on the code of every error it might report.
"""

from __future__ import annotations

import signal
import sys


class EskinError(Exception):
    """Something the user can fix: bad data, a board that misbehaves, a missing run.
    The message says what and where, in one line."""


# What a Ctrl-C leaves, said after "eskin: interrupted; ". Each is true of the steps
# that give it: acquisition appends every frame to its log as it comes; a DVC stage
# writes its outputs at its end, after DVC removed the old ones, and dvc.lock records
# them only when it succeeds.
RECEIVED_KEPT = "everything received so far is on disk, rerun to resume"
STAGE_NOT_KEPT = ("this stage's outputs are not recorded in dvc.lock (any it wrote are "
                  "incomplete): `dvc repro` runs it again from the start")
TRACK_KEPT = ("the task runs logged so far stay in MLflow, the one it was logging "
              "incomplete and marked FAILED; dvc.lock does not record this stage: "
              "`dvc repro` runs it again")
TASKS_KEPT = ("the tasks it finished are kept, and `dvc repro` runs it again for the "
              "rest (this stage's outputs are not recorded in dvc.lock until then)")
STEP_NOT_KEPT = "what it writes at its end may be missing or incomplete: run it again"
NOTHING_CHANGED = "nothing was changed"
STOPPED = "it stopped before it finished"  # a command that says nothing of its own


def _terminated(signum, frame) -> None:
    raise SystemExit(128 + signum)


def run_friendly(call, *, debug: bool = False, interrupted: str = STAGE_NOT_KEPT) -> int:
    """Run ``call``; turn the errors a user can act on into one line and exit code 1, and
    Ctrl-C into one line saying what is kept (``interrupted``: by default, a DVC stage's)
    and exit code 130."""
    # SIGTERM (`dvc queue kill`, a supervisor) unwinds like an exception: an open MLflow
    # run is closed as FAILED, worker processes are shut down, the raw log is flushed.
    signal.signal(signal.SIGTERM, _terminated)
    for stream in (sys.stdout, sys.stderr):  # an ASCII-only terminal: escape, never crash
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="backslashreplace")
    try:
        return call() or 0
    except KeyboardInterrupt:
        print(f"eskin: interrupted; {interrupted}", file=sys.stderr)
        return 130
    except (EskinError, ValueError, KeyError, FileNotFoundError) as err:
        if debug:
            raise
        message = err.args[0] if isinstance(err, KeyError) and err.args else err
        print(f"eskin: error: {message}", file=sys.stderr)
        return 1
