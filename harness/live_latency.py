"""How fast the trained stack turns frames into estimates, live.

For each scene, the stack as scikit-learn runs it (``SkinStack``, from the workspace) and
as exported (``ExportedStack``, ``models/<scene>/stack.onnx`` run by onnxruntime), on
frames of the scene's dataset:

* per frame: ``predict`` on one frame at a time, as a robot loop that asks for every
  frame the moment it arrives does — median and 99th percentile, against the budget of
  1 ms a frame;
* per batch: what ``eskin live`` does, predicting together the frames that arrived while
  the last batch was predicted — the frames per second it sustains, against the board's
  frame rate (the Python board's 12 ms period, 83 frames/s; the firmware's 56.8 frames/s);
* the baseline, in the same process: the same frames through the featurizer alone, the
  part of a call every model pays (input checks, DataFrame), so the ratio says what the
  models add.

    PYTHONPATH=. python -m harness.live_latency [--frames 500] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import pandas as pd

from eskin.catalog import processed_path, stack_path
from eskin.deploy.stack import ExportedStack, SkinStack

BUDGET_MS = 1.0
FRAMES = 500  # sampled from each scene's dataset
BOARD_FPS = {"python board": 1000 / 12, "firmware": 56.8}


def timed(call, items) -> np.ndarray:
    """Milliseconds of ``call(item)`` for each item."""
    out = []
    for item in items:
        started = time.perf_counter()
        call(item)
        out.append((time.perf_counter() - started) * 1000)
    return np.array(out)


def sustained_fps(stack: SkinStack | ExportedStack, frames: np.ndarray, period_s: float) -> float:
    """Frames per second the live loop keeps up with: frames arrive every ``period_s``;
    each call predicts all that arrived during the last one (simulated clock)."""
    clock, done, i = 0.0, 0, 0
    while i < len(frames):
        arrived = max(i + 1, min(len(frames), int(clock / period_s) + 1))
        started = time.perf_counter()
        stack.predict(frames[i:arrived])
        clock = max(clock, (arrived - 1) * period_s) + time.perf_counter() - started
        done = i = arrived
    return done / clock


def timings(stack, frames: np.ndarray) -> dict:
    stack.predict(frames[:2])  # warm up
    per_frame = timed(stack.predict, frames[:, None, :])
    started = time.perf_counter()
    stack.predict(frames)
    return {"per_frame_median_ms": float(np.median(per_frame)),
            "per_frame_p99_ms": float(np.percentile(per_frame, 99)),
            "one_batch_ms_per_frame": (time.perf_counter() - started) * 1000 / len(frames),
            "sustained_fps": {name: sustained_fps(stack, frames, 1 / fps)
                              for name, fps in BOARD_FPS.items()}}


def measure(scene: str, n: int, root: Path = Path(".")) -> dict:
    stack = SkinStack.from_workspace(scene, root)
    exported = ExportedStack.from_file(root / stack_path(scene))
    channels = stack.skin.channels
    data = pd.read_parquet(root / processed_path(scene), columns=channels)
    frames = data.sample(n, random_state=0).to_numpy(dtype=np.float64)
    baseline = timed(lambda row: stack.featurizer.transform(pd.DataFrame(row, columns=channels)),
                     frames[:, None, :])
    return {"scene": scene, "frames": n, "baseline_median_ms": float(np.median(baseline)),
            "stacks": {"scikit-learn": timings(stack, frames), "onnx": timings(exported, frames)}}


def render(results: list[dict]) -> str:
    lines = ["| scene | stack | per frame, median | p99 | vs 1 ms budget | featurizer alone "
             "(baseline) | stack ÷ baseline | whole batch, per frame | keeps up with |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        for name, t in r["stacks"].items():
            keeps = ", ".join(f"{board} ({fps:.0f}/s: {t['sustained_fps'][board]:.0f}/s)"
                              for board, fps in BOARD_FPS.items()
                              if t["sustained_fps"][board] >= 0.98 * fps) or "neither board"
            median = t["per_frame_median_ms"]
            verdict = "within" if median <= BUDGET_MS else "over"
            lines.append(
                f"| {r['scene']} | {name} | {median:.3f} ms | {t['per_frame_p99_ms']:.3f} ms"
                f" | {median / BUDGET_MS:.2f}× ({verdict}) | {r['baseline_median_ms']:.3f} ms"
                f" | {median / r['baseline_median_ms']:.1f}× | "
                f"{t['one_batch_ms_per_frame'] * 1000:.0f} µs | {keeps} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=FRAMES)
    parser.add_argument("--scenes", nargs="+", required=True, help="scenes of params.yaml")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    results = [measure(scene, args.frames) for scene in args.scenes]
    print(render(results))
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
