"""What localising one contact costs per row as a skin grows (issue 59), for each model a
scene of that size may train: the multinomial logistic regression on every channel and
PeakWindow, against the logistic regression on the paper's 10 × 10 in the same run.

Each size is a simulated single-force scene of the paper's plan (three stretches, three
forces, every node) on an N × N skin, 5 samples a condition, seeded from params.yaml's
``sim``; each model is fitted once to x and once to y on its contact rows, on one thread,
and timed in CPU seconds (the fit of one fold, as cross-validation runs it).

    PYTHONPATH=. python -m harness.localise_cost [N ...] [--json FILE]   (default 10 14 16 32)
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

from eskin.config.base import load_params
from eskin.config.params import Params
from eskin.data.plan import single_force_plan
from eskin.data.schema import contact_mask
from eskin.device.physics import SkinParams
from eskin.learning.estimators import build_model
from eskin.skin import Skin
from harness.calibrate import simulate_plan

MODELS = ("logistic", "peak_window")
BASELINE = (10, "logistic")  # the paper's skin and its default
SAMPLES = 5


def cost(size: int, sim: SkinParams, stretches, forces) -> dict[str, float]:
    """CPU ms per contact row of fitting each of :data:`MODELS` to x and y on an N × N skin."""
    skin = Skin(size, size)
    plan = single_force_plan(f"s{size}", stretches, forces, samples=SAMPLES, skin=skin)
    frame = simulate_plan(sim, plan, seed=1)
    frame = frame[contact_mask(frame)].reset_index(drop=True)
    out = {"rows": len(frame)}
    for name in MODELS:
        started = time.process_time()
        for target in ("x", "y"):
            build_model("localise", name, {}, skin).fit(frame[skin.channels], frame[target])
        out[name] = 1000 * (time.process_time() - started) / len(frame)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sizes", nargs="*", type=int, default=[10, 14, 16, 32])
    parser.add_argument("--json", type=Path, help="also write the table here")
    args = parser.parse_args()
    if os.environ.get("OMP_NUM_THREADS") != "1":
        raise SystemExit("run with OMP_NUM_THREADS=1: the cost is one thread's")
    params = load_params(Params)
    sim = SkinParams.from_mapping(params.sim.model_dump())
    scene = params.scenes["single_force"]
    stretches, forces = scene.stretches, [f for f in scene.forces if f > 0]
    sizes = sorted({BASELINE[0], *args.sizes})
    table = {size: cost(size, sim, stretches, forces) for size in sizes}
    base = table[BASELINE[0]][BASELINE[1]]
    print(f"CPU ms per contact row of a localisation fit (x and y), and the ratio to "
          f"{BASELINE[1]} on {BASELINE[0]} × {BASELINE[0]} ({base:.3f} ms)")
    print(f"{'skin':>8} {'rows':>7} " + " ".join(f"{m:>20}" for m in MODELS))
    for size, row in table.items():
        cells = " ".join(f"{row[m]:8.3f} ms {row[m] / base:6.1f}×" for m in MODELS)
        print(f"{size:>3} × {size:<3} {row['rows']:>7} {cells}")
    if args.json:
        args.json.write_text(json.dumps({"baseline": list(BASELINE), "ms_per_row": table},
                                        indent=2) + "\n")


if __name__ == "__main__":
    main()
