"""DVC stage of `make bench`: what localising one contact costs per row as a skin grows
(harness/localise_cost.py), against the logistic regression on the paper's 10 × 10."""

import json
import sys
from pathlib import Path

from eskin.config.acquisition import Sim
from eskin.config.base import BENCH_PARAMS, load_params, sections
from eskin.config.scenes import Scenes
from eskin.device.physics import SkinParams
from eskin.errors import run_friendly
from harness.localise_cost import markdown, measure, paper_plan
from harness.params import Bench

REPORT = Path("reports")


def main() -> int:
    params = load_params(sections(sim=Sim, scenes=Scenes))
    sizes = load_params(sections(BENCH_PARAMS, bench=Bench)).bench.localise_sizes
    doc = measure(sizes, SkinParams.from_mapping(params.sim.model_dump()), *paper_plan(params))
    (REPORT / "localise_cost.json").write_text(json.dumps(doc, indent=2) + "\n")
    (REPORT / "localise_cost.md").write_text(markdown(doc))
    print(markdown(doc), end="")
    return 0


if __name__ == "__main__":
    sys.exit(run_friendly(main))
