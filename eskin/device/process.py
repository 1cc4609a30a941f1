"""A board that runs as a child process: the Python board, or the firmware under simavr.

Both are started, waited for and stopped the same way: the child's stderr goes to a file,
not a pipe nobody drains (a chatty child can never block on a full pipe, and a traceback is
kept whole for the error message); its first line on stdout (the port to open) is waited
for with a deadline; an error while it runs says what the child said if it had died; and it
is stopped for sure (terminate, then kill).
"""

from __future__ import annotations

import contextlib
import selectors
import subprocess
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from eskin.device.link import LinkError
from eskin.errors import EskinError

STDERR_TAIL = 2000  # characters of a dead child's stderr quoted in the error


@dataclass
class ChildBoard:
    process: subprocess.Popen
    first_line: str
    stderr: Path

    def said(self) -> str:
        return self.stderr.read_text(errors="replace").strip()[-STDERR_TAIL:]


@contextlib.contextmanager
def child_board(command: Sequence[str], *, name: str, workdir: Path,
                start_timeout_s: float = 30.0, stdin: int = subprocess.DEVNULL
                ) -> Iterator[ChildBoard]:
    """Run ``command``; yield it once its first line is out. ``name`` says what it is in
    errors; its stderr is kept in ``workdir``; ``stdin=subprocess.PIPE`` to talk to it."""
    errors = workdir / f"{Path(command[0]).name}.stderr"
    with errors.open("w") as stderr:
        process = subprocess.Popen(list(command), stdin=stdin, stdout=subprocess.PIPE,
                                   stderr=stderr, text=True, bufsize=1)
    try:
        with selectors.DefaultSelector() as selector:
            selector.register(process.stdout, selectors.EVENT_READ)
            if not selector.select(start_timeout_s):
                raise LinkError(f"{name} did not start within {start_timeout_s:g} s")
        child = ChildBoard(process, process.stdout.readline().strip(), errors)
        if not child.first_line:
            process.wait(timeout=5)
            raise LinkError(f"{name} exited ({process.returncode}): {child.said()}")
        try:
            yield child
        except EskinError as err:
            if process.poll() is not None:  # the board died: that is the news
                raise LinkError(f"{err}\n{name} had exited ({process.returncode}): "
                                f"{child.said()}") from err
            raise
    finally:
        process.terminate()
        try:
            process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
