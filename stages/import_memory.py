"""DVC stage of `make bench`: peak memory of importing large CSVs (harness/memory_bench.py)."""

import json
import sys
from pathlib import Path

from eskin.config.base import BENCH_PARAMS, load_params, sections
from eskin.errors import run_friendly
from harness.memory_bench import import_memory, markdown
from harness.params import Bench

REPORT = Path("reports")


def main() -> int:
    rows = load_params(sections(BENCH_PARAMS, bench=Bench)).bench.import_rows
    results = import_memory([int(n) for n in rows])
    (REPORT / "import_memory.json").write_text(json.dumps(results, indent=2) + "\n")
    (REPORT / "import_memory.md").write_text(markdown(results))
    print(markdown(results))
    return 0


if __name__ == "__main__":
    sys.exit(run_friendly(main))
