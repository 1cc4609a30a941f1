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


def _terminated(signum, frame) -> None:
    raise SystemExit(128 + signum)


def run_friendly(call, *, debug: bool = False) -> int:
    """Run ``call``; turn the errors a user can act on into one line and exit code 1."""
    # SIGTERM (`dvc queue kill`, a supervisor) unwinds like an exception: an open MLflow
    # run is closed as FAILED, worker processes are shut down, the raw log is flushed.
    signal.signal(signal.SIGTERM, _terminated)
    for stream in (sys.stdout, sys.stderr):  # an ASCII-only terminal: escape, never crash
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="backslashreplace")
    try:
        return call() or 0
    except KeyboardInterrupt:
        print("eskin: interrupted; everything received so far is on disk, rerun to resume",
              file=sys.stderr)
        return 130
    except (EskinError, ValueError, KeyError, FileNotFoundError) as err:
        if debug:
            raise
        message = err.args[0] if isinstance(err, KeyError) and err.args else err
        print(f"eskin: error: {message}", file=sys.stderr)
        return 1
