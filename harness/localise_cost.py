"""What localising one contact costs per row as a skin grows (issue 59), for each model a
scene of that size may train: the multinomial logistic regression on every channel and
PeakWindow, against the logistic regression on the paper's 10 × 10 in the same run.

Each size is a simulated single-force scene of the paper's plan (three stretches, three
forces, every node) on an N × N skin, 5 samples a condition, seeded from params.yaml's
``sim``; each model is fitted once to x and once to y on its contact rows, on one thread,
and timed in CPU seconds (the fit of one fold, as cross-validation runs it).

    PYTHONPATH=. python -m harness.localise_cost [N ...] [--json FILE]

(default 10 14 16 32); `make bench` runs it as the stage ``localise_cost`` on
``bench.localise_sizes``, into reports/localise_cost.json and .md.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from threadpoolctl import threadpool_limits

from eskin.data.plan import single_force_plan
from eskin.data.schema import contact_mask
from eskin.device.physics import SkinParams
from eskin.errors import EskinError, run_friendly
from eskin.kinds import ONE_CONTACT
from eskin.learning.estimators import build_model
from eskin.skin import skin_from_dict
from harness.calibrate import simulate_plan

MODELS = ("logistic", "peak_window")
BASELINE = (10, "logistic")  # the paper's skin and its default
SAMPLES = 5


def cost(size: int, sim: SkinParams, stretches, forces) -> dict[str, float]:
    """CPU ms per contact row of fitting each of :data:`MODELS` to x and y on an N × N skin."""
    skin = skin_from_dict({"rows": size, "columns": size})
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


def measure(sizes, sim: SkinParams, stretches, forces) -> dict[str, Any]:
    """Every size's cost per row (:func:`cost`), the baseline's among them, and each one's
    ratio to the baseline."""
    sizes = sorted({BASELINE[0], *map(int, sizes)})
    with threadpool_limits(limits=1):  # one thread's cost, as a fold's fit in a pool
        table = {str(size): cost(size, sim, stretches, [f for f in forces if f > 0])
                 for size in sizes}
    base = table[str(BASELINE[0])][BASELINE[1]]
    for row in table.values():
        row["ratio"] = {name: row[name] / base for name in MODELS}
    return {"baseline": {"size": BASELINE[0], "model": BASELINE[1], "ms_per_row": base},
            "samples": SAMPLES, "ms_per_row": table}


def markdown(doc: dict[str, Any]) -> str:
    base = doc["baseline"]
    lines = [f"CPU ms per contact row of a localisation fit (x and y, one thread), and its "
             f"ratio to {base['model']} on {base['size']} × {base['size']} "
             f"({base['ms_per_row']:.3f} ms)", "",
             "| skin | contact rows | " + " | ".join(MODELS) + " |",
             "|---|---|" + "---|" * len(MODELS)]
    for size, row in doc["ms_per_row"].items():
        lines.append(f"| {size} × {size} | {row['rows']:,} | " + " | ".join(
            f"{row[name]:.3f} ms ({row['ratio'][name]:.1f}×)" for name in MODELS) + " |")
    return "\n".join(lines) + "\n"


def paper_plan(params) -> tuple[list[float], list[float]]:
    """The stretches and forces of the first one-contact scene params.yaml declares."""
    scene = next((s for s in params.scenes.values() if s.kind == ONE_CONTACT.name), None)
    if scene is None:
        raise EskinError("params.yaml declares no one-contact scene to take the plan from")
    return list(scene.stretches), list(scene.forces)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sizes", nargs="*", type=int, default=[10, 14, 16, 32])
    parser.add_argument("--json", type=Path, help="also write the table here")
    args = parser.parse_args()
    from eskin.config.base import load_params
    from eskin.config.params import Params  # the whole params.yaml: the CLI's, not the stage's

    params = load_params(Params)
    doc = measure(args.sizes, SkinParams.from_mapping(params.sim.model_dump()),
                  *paper_plan(params))
    print(markdown(doc), end="")
    if args.json:
        args.json.write_text(json.dumps(doc, indent=2) + "\n")


if __name__ == "__main__":
    sys.exit(run_friendly(main))
