"""The code a step runs, by content: a module and every eskin module it imports, at any
depth and inside functions (:mod:`modulefinder` reads their bytecode and runs nothing).
A step keeps what it made from the same inputs and the same code (the train step's tasks,
the export step's stacks); these files are what "the same code" means."""

from __future__ import annotations

import functools
from modulefinder import ModuleFinder
from pathlib import Path

from eskin.steps.keep import files_md5

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
    return files_md5(code_files(script), _ROOT)


class _EskinModules(ModuleFinder):
    """A module finder that follows eskin's own imports only."""

    def import_module(self, partname, fqname, parent):
        if fqname.split(".")[0] != "eskin":
            return None
        return super().import_module(partname, fqname, parent)
