"""The code a step runs, by content: a module and every eskin module it imports, at any
depth and inside functions (:mod:`modulefinder` reads their bytecode and runs nothing).
A step keeps what it made from the same inputs and the same code (the train step's tasks,
the export step's stacks); these files are what "the same code" means."""

from __future__ import annotations

import functools
import hashlib
from modulefinder import ModuleFinder
from pathlib import Path

_ROOT = Path(__file__).resolve().parents[2]  # the directory that holds the eskin package


@functools.cache
def code_files(script: str) -> tuple[Path, ...]:
    """``script`` (a module's file) and every eskin module it imports."""
    finder = _EskinModules(path=[str(_ROOT)])
    finder.run_script(script)
    return tuple(sorted({Path(module.__file__).resolve() for module in finder.modules.values()
                         if module.__file__}))


def code_md5(script: str) -> str:
    """The md5 of :func:`code_files`, each by its path under the package's parent, so that
    the same code gives the same md5 in any checkout."""
    digest = hashlib.md5()
    for path in code_files(script):
        digest.update(path.relative_to(_ROOT).as_posix().encode() + b"\0")
        digest.update(hashlib.md5(path.read_bytes()).hexdigest().encode() + b"\n")
    return digest.hexdigest()


class _EskinModules(ModuleFinder):
    """A module finder that follows eskin's own imports only."""

    def import_module(self, partname, fqname, parent):
        if fqname.split(".")[0] != "eskin":
            return None
        return super().import_module(partname, fqname, parent)
