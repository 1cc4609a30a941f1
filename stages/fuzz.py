"""DVC stage of `make bench`: fuzz the frame parser or the import reader (harness/fuzz.py)."""

import json
import sys
from pathlib import Path

from eskin.config.base import BENCH_PARAMS, load_params, sections
from eskin.errors import run_friendly
from harness import fuzz
from harness.params import Fuzz

TARGETS = {"parser": fuzz.fuzz_parser, "import": fuzz.fuzz_import}


def main(target: str) -> int:
    examples = int(load_params(sections(BENCH_PARAMS, fuzz=Fuzz)).fuzz.examples)
    result = TARGETS[target](examples, progress=True)
    out = Path("reports/fuzz") / f"{target}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: main(sys.argv[1])))
