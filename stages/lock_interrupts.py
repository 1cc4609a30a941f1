"""DVC stage of `make bench`: how often a Ctrl-C at a random time leaves dvc.lock damaged,
under a plain `dvc repro` and under `make repro`'s `python -m eskin.lockfile repro`
(harness/lock_interrupts.py), on a stub of the pipeline: its stages, a stub command each."""

import json
import sys
from pathlib import Path

from eskin.errors import run_friendly
from harness.lock_interrupts import measure, render

REPORT = Path("reports/lock_interrupts")


def main() -> str:
    result = measure(log=lambda line: print(line, file=sys.stderr, flush=True))
    REPORT.mkdir(parents=True, exist_ok=True)
    (REPORT / "default.json").write_text(json.dumps(result, indent=2) + "\n")
    text = render(result) + "\n"
    (REPORT / "default.md").write_text(text)
    return text


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main())))
