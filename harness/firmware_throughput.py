"""Frames per second through the firmware at 115200 baud, against the line's limit.

``python -m harness.firmware_throughput [frames [scene]]`` runs the firmware built for the
scene's skin (the paper's without a scene) under simavr, asks for ``frames`` frames in one
``SAMPLE``, and prints the
rate in the board's own time (its ``t_ms``: the emulated clock, what a real Uno would
do), the limit the serial line sets (bytes per frame × 10 bits per byte at 8N1 /
115200 baud), their ratio, the emulator's speed against real time, and how long each
simulated scene on that skin takes to sample on a real bench.
"""

from __future__ import annotations

import sys
import time

import serial

from eskin.config.base import load_params
from eskin.config.params import Params
from eskin.config.scenes import get_scene, scene_skin
from eskin.data.plan import plan_from_params
from eskin.device.emulated import emulated_board
from eskin.device.physics import SkinParams, skin_params
from eskin.device.protocol import Frame, parse_line
from eskin.skin import PAPER_SKIN, AnySkin

BAUD = 115200
BITS_PER_BYTE = 10  # 8N1: start, 8 data, stop


def measure(sim: SkinParams, frames: int, skin: AnySkin) -> dict[str, float]:
    with emulated_board(sim, skin=skin, rest_length_mm=101.0, samples=frames) as (port, rig):
        link = serial.Serial(port, BAUD, timeout=30)
        # the greeting: the boot one may be cut (sent before the port was open); the fence
        # after HELLO says every greeting has arrived
        link.write(b"HELLO\nSTREAM OFF\n")
        while link.readline() not in (b"#OK STREAM OFF\n", b""):
            pass
        rig.place(1, [(min(5, skin.rows), min(5, skin.columns), 3.2536)])
        started = time.monotonic()
        link.write(b"SAMPLE %d\n" % frames)
        received = []
        while isinstance(event := parse_line((line := link.readline()).rstrip(b"\n"),
                                             skin.terminals), Frame):
            received.append((event.t_ms, len(line)))
        wall = time.monotonic() - started
    if len(received) != frames:
        raise RuntimeError(f"asked for {frames} frames, got {len(received)}, then {event}")
    board_s = (received[-1][0] - received[0][0]) / 1000
    per_frame_bytes = sum(n for _, n in received) / frames
    line_limit = BAUD / (per_frame_bytes * BITS_PER_BYTE)
    rate = (frames - 1) / board_s
    return {"frames": frames, "board_s": board_s, "frames_per_s": rate,
            "bytes_per_frame": per_frame_bytes, "line_limit_per_s": line_limit,
            "share_of_line": rate / line_limit, "wall_s": wall,
            "emulation_speed": board_s / wall}


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    frames = int(args[0]) if args else 500
    params = load_params(Params)
    skin = scene_skin(get_scene(params, args[1])) if len(args) > 1 else PAPER_SKIN
    sim = skin_params(params.sim)
    m = measure(sim, frames, skin)
    print(f"the {skin.describe()}: {m['frames']} frames in {m['board_s']:.2f} s of board time: "
          f"{m['frames_per_s']:.1f} frames/s")
    print(f"line limit at {BAUD} baud: {m['bytes_per_frame']:.1f} bytes a frame → "
          f"{m['line_limit_per_s']:.1f} frames/s; the firmware reaches "
          f"{m['share_of_line']:.0%} of it")
    print(f"emulation: {m['wall_s']:.2f} s wall for {m['board_s']:.2f} s of board time "
          f"({m['emulation_speed']:.2f}× real time)")
    for name, scene in params.scenes.items():
        if scene.source != "simulated" or scene_skin(scene) != skin:
            continue
        plan = plan_from_params(name, scene)
        n = len(plan.conditions) * plan.samples
        print(f"scene {name}: {len(plan.conditions):,} conditions × {plan.samples} samples = "
              f"{n:,} frames: {n / m['frames_per_s'] / 60:.1f} min of sampling on a real "
              "bench, plus placing the weights by hand")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
