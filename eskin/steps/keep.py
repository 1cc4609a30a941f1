"""What a step made, kept when made again from the same inputs: the export's stacks and
the report. A record (JSON, under ``.cache/``, not a DVC output) names the inputs by
value and the outputs by md5; a step keeps its outputs while both still hold."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Sequence
from pathlib import Path

from eskin.data.schema import md5_file


def files_md5(files: Iterable[Path], root: Path) -> str:
    """The md5 of ``files`` (under ``root``) by their paths relative to it and their
    bytes' md5s: the same files give the same md5 wherever ``root`` is."""
    digest = hashlib.md5()
    for file in sorted(Path(f) for f in files):
        digest.update(file.relative_to(root).as_posix().encode() + b"\0")
        digest.update(md5_file(file).encode() + b"\n")
    return digest.hexdigest()


def tree_md5(path: Path) -> str:
    """The md5 of a file (its bytes', as DVC records it), or of a directory's files by
    their relative paths ("" for neither)."""
    path = Path(path)
    if path.is_file():
        return md5_file(path)
    if not path.is_dir():
        return ""
    return files_md5((p for p in path.rglob("*") if p.is_file()), path)


def kept(root: Path, record: Path, inputs: dict, outputs: Sequence[Path]) -> bool:
    """Whether ``record`` says ``outputs`` (paths under ``root``) were made from
    ``inputs``, and they are still what was made."""
    try:
        recorded = json.loads(Path(record).read_text())
    except (OSError, ValueError):
        return False
    made = recorded.get("outputs_md5", {})
    return (all(recorded.get(key) == value for key, value in inputs.items())
            and set(made) == {Path(p).as_posix() for p in outputs}
            and all(made[Path(p).as_posix()] and made[Path(p).as_posix()]
                    == tree_md5(Path(root) / p) for p in outputs))


def write_record(root: Path, record: Path, inputs: dict, outputs: Sequence[Path]) -> None:
    """``record``: ``outputs``, just made from ``inputs``."""
    record = Path(record)
    record.parent.mkdir(parents=True, exist_ok=True)
    record.write_text(json.dumps({**inputs, "outputs_md5": {
        Path(p).as_posix(): tree_md5(Path(root) / p) for p in outputs}}, indent=2) + "\n")
