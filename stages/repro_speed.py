"""DVC stage of `make bench`: the daily loop's speed against a baseline revision's pipeline
(harness/repro_speed.py): the full `dvc repro` from an empty cache, a one-knob experiment,
a training stage's fixed cost, and the headline scores beside their fold spreads, both
revisions measured in this run; then the floor DVC and Python set under each of them."""

import json
import sys
from pathlib import Path

from eskin.config.base import BENCH_PARAMS, load_params, sections
from eskin.errors import run_friendly
from harness.params import Bench
from harness.repro_speed import measure, render

REPORT = Path("reports/repro_speed")


def main() -> str:
    result = measure(str(load_params(sections(BENCH_PARAMS, bench=Bench)).bench.repro_baseline),
                     log=lambda line: print(line, file=sys.stderr, flush=True))
    REPORT.mkdir(parents=True, exist_ok=True)
    (REPORT / "default.json").write_text(json.dumps(result, indent=2) + "\n")
    text = render(result) + "\n"
    (REPORT / "default.md").write_text(text)
    return text


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main())))
