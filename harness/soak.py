"""Soak: a whole scene acquired over a faulty link, killed with SIGKILL on the way,
compared sample by sample with a clean acquisition of the same seed.

Each run is ``eskin acquire`` in its own process, as a user runs it; the
simulated board behind it injects every fault kind of
:mod:`eskin.device.faults` and logs each one. The first runs are killed
(SIGKILL: nothing gets to clean up) once a given share of the scene's
conditions is complete; the last run resumes and finishes. The dataset then
built from the raw log must equal the clean one in every channel, label and
provenance column except the board's own counters (``seq``, ``t_ms``: a
retried condition uses more wire traffic, and a reset restarts them).

``transport``: ``pty`` (the scene's own simulated board, one per run, as `eskin acquire`
starts it) or ``socket`` (one simulated board for the whole soak, served with `eskin
device simulate --socket 0`, and the scene acquired from it as a serial board at its
``socket://`` port, its indenters placed by ``SIM`` commands). The board logs every
``SAMPLE`` request with the faults, so the result counts requests per condition and
frames asked per frame stored across the SIGKILLs too.

    python -m harness.soak single_force --transport socket --drop 0.05 --corrupt 0.05 \
        --ok-dup 0.01 --ok-spoof 0.01 --out reports/soak-link
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import signal
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml

from eskin.config.base import untraced, validate_params
from eskin.config.params import Params
from eskin.data.plan import ScenePlan, plan_from_params
from eskin.data.schema import LABELS
from eskin.device.faults import KINDS
from eskin.steps.ingest import ingest_at
from harness.params import Soak

KEY = ["trial", "sample"]


class SoakError(RuntimeError):
    """A soak run ended in a way the soak did not plan (the message has its stderr)."""


@dataclass
class SoakResult:
    scene: str
    conditions: int
    rows_expected: int
    rows: int
    faults: dict[str, int]
    kills: int
    killed_after: list[int]        # complete conditions in the log at each SIGKILL
    lost: int                      # clean samples missing from the soaked dataset
    duplicated: int                # (trial, sample) stored more than once
    extra: int                     # samples the clean run does not have
    differing: int                 # samples present in both whose values differ
    crc_passed: int                # attempts asked again for a frame that passed its
                                   # CRC-8 with digits lost (a reading or t_ms)
    seconds: float
    runs: list[str] = field(default_factory=list)   # each run's summary or how it ended
    transport: str = "pty"
    requests: int = 0              # SAMPLE requests the board answered (or was sent)
    frames_requested: int = 0      # the frames they asked for
    # Each differing sample, and the raw-log records of the attempt that stored it: what
    # a failed soak (a rare one in CI, say) is diagnosed from once its files are gone.
    evidence: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return (self.lost == self.duplicated == self.extra == self.differing == 0
                and self.rows == self.rows_expected and all(self.faults.values()))

    @property
    def requests_per_condition(self) -> float:
        return self.requests / self.conditions if self.conditions else 0.0

    @property
    def frames_requested_per_stored(self) -> float:
        return self.frames_requested / self.rows if self.rows else 0.0

    def as_dict(self) -> dict[str, Any]:
        return {**asdict(self), "faults_total": sum(self.faults.values()), "passed": self.passed,
                "requests_per_condition": round(self.requests_per_condition, 3),
                "frames_requested_per_stored": round(self.frames_requested_per_stored, 3)}

    def markdown(self) -> str:
        faults = " · ".join(f"{k} {v}" for k, v in self.faults.items())
        lines = [
            f"# Soak: {self.scene} over a faulty link ({self.transport}), {self.kills} "
            "SIGKILL(s)",
            "",
            "| | |", "|---|---|",
            f"| conditions | {self.conditions} |",
            f"| samples expected / stored | {self.rows_expected} / {self.rows} |",
            f"| faults injected | {sum(self.faults.values())} ({faults}) |",
            f"| SIGKILLs (complete conditions at each) | {self.kills} "
            f"({', '.join(map(str, self.killed_after))}) |",
            f"| lost / duplicated / extra / differing | {self.lost} / {self.duplicated} / "
            f"{self.extra} / {self.differing} |",
            f"| damaged frames that passed CRC-8, caught by the digit checks | "
            f"{self.crc_passed} |",
            f"| SAMPLE requests (per condition) | {self.requests} "
            f"({self.requests_per_condition:.2f}) |",
            f"| frames asked (per frame stored) | {self.frames_requested} "
            f"({self.frames_requested_per_stored:.3f}) |",
            f"| wall time | {self.seconds:.0f} s |",
            f"| verdict | {'PASS' if self.passed else 'FAIL'} |",
            "", "Runs:", "",
            *[f"{i}. {text}" for i, text in enumerate(self.runs, start=1)],
            *(["", "Evidence:", "", "```", *self.evidence, "```"] if self.evidence else []),
        ]
        return "\n".join(lines) + "\n"


def soak_params(params: Params, settings: Soak, fault_log: Path, scene: str) -> dict[str, Any]:
    """The project's params (as written) with the soak's faults and timeouts, and
    ``scene`` alone, simulated. What the soak reads is the ``sim``, ``sim_board``,
    ``acquire``, ``ingest`` and ``soak`` sections and the scene's; the rest only makes a
    whole params file for `eskin acquire`."""
    out = untraced(params).model_dump(exclude_unset=True)
    out.update(sim=params.sim.model_dump(exclude_unset=True),
               sim_board=params.sim_board.model_dump(exclude_unset=True),
               acquire=params.acquire.model_dump(exclude_unset=True),
               ingest=params.ingest.model_dump(exclude_unset=True),
               scenes={scene: {**params.scenes[scene].model_dump(exclude_unset=True),
                               "source": "simulated"}})
    out["sim_board"]["corrupt_fraction"] = float(settings.corrupt_fraction)
    out["sim_board"]["faults"] = {**settings.faults.model_dump(exclude_unset=True),
                                  "log": str(fault_log)}
    out["acquire"].update(timeout_s=float(settings.timeout_s),
                          reconnect_s=float(settings.reconnect_s))
    return out


def _merged(reference: pd.DataFrame, frame: pd.DataFrame, plan: ScenePlan
            ) -> tuple[list[str], pd.DataFrame, np.ndarray]:
    """The columns compared (channels, labels, session), ``reference`` and ``frame``
    outer-merged on the sample (suffixes ``_clean``, ``_soak``; the board counters too),
    and which of the merged rows are in both and differ."""
    values = plan.skin.channels + LABELS[plan.kind] + ["session"]
    columns = KEY + values + ["seq", "t_ms"]
    merged = reference[columns].merge(frame[columns].drop_duplicates(KEY), on=KEY,
                                      how="outer", suffixes=("_clean", "_soak"),
                                      indicator=True)
    differs = np.zeros(len(merged), dtype=bool)
    for column in values:
        differs |= (merged[f"{column}_clean"] != merged[f"{column}_soak"]).to_numpy()
    return values, merged, differs & (merged["_merge"] == "both").to_numpy()


def compare(reference: pd.DataFrame, frame: pd.DataFrame, plan: ScenePlan) -> dict[str, int]:
    """Lost, duplicated, extra and differing samples of ``frame`` against ``reference``, the
    datasets of ``plan``."""
    _, merged, differs = _merged(reference, frame, plan)
    return {"lost": int((merged["_merge"] == "left_only").sum()),
            "duplicated": int(frame.duplicated(KEY).sum()),
            "extra": int((merged["_merge"] == "right_only").sum()),
            "differing": int(differs.sum())}


def differing_evidence(reference: pd.DataFrame, frame: pd.DataFrame, plan: ScenePlan,
                       log: Path, *, at_most: int = 3) -> list[str]:
    """For the first ``at_most`` samples whose values differ from ``reference``: which
    columns, both values, the board counters of each, and the raw-log records (bounded)
    of the attempt whose frame line was stored for it."""
    values, merged, differs = _merged(reference, frame, plan)
    records = log.read_text(encoding="ascii", errors="replace").splitlines()
    out = []
    for _, row in merged[differs].head(at_most).iterrows():
        changed = ", ".join(f"{c} {row[f'{c}_clean']} -> {row[f'{c}_soak']}" for c in values
                            if row[f"{c}_clean"] != row[f"{c}_soak"])
        out.append(f"trial {row['trial']} sample {row['sample']}: {changed} (clean seq "
                   f"{row['seq_clean']:.0f} t_ms {row['t_ms_clean']:.0f}; soak seq "
                   f"{row['seq_soak']:.0f} t_ms {row['t_ms_soak']:.0f})")
        prefix = f"D,{int(row['seq_soak'])},{int(row['t_ms_soak'])},"
        attempts = {line.split("\t")[1] for line in records
                    if line.startswith("F\t") and line.split("\t")[2].startswith(prefix)}
        held = [line[:160] for line in records
                if line[:1] in "BFXE" and line.split("\t")[1:2] and
                line.split("\t")[1] in attempts]
        out += [f"  {line}" for line in held[:40]]
    return out


def expected_kinds(settings: Soak) -> list[str]:
    """The fault kinds the soak's settings inject (their counts must not be 0)."""
    rates = settings.faults.model_dump()
    return [kind for kind in KINDS
            if (settings.corrupt_fraction if kind == "corrupt" else rates.get(kind, 0.0)) > 0]


@contextlib.contextmanager
def socket_board(workdir: Path, scene: str) -> Iterator[str]:
    """The simulated board of ``workdir``'s params.yaml (its sim, sim_board and faults, the
    scene's skin) served on a loopback socket for the whole soak; yields its port."""
    board = subprocess.Popen([sys.executable, "-m", "eskin", "device", "simulate", "--socket",
                              "0", "--scene", scene], cwd=workdir, stdout=subprocess.PIPE,
                             stderr=subprocess.DEVNULL, text=True)
    try:
        port = board.stdout.readline().strip()
        if not port.startswith("socket://"):
            raise SoakError(f"the simulated board did not announce a socket port: {port!r}")
        yield port
    finally:
        board.terminate()
        board.wait(timeout=10)


def run_soak(params: Params, settings: Soak, workdir: Path,
             reference: pd.DataFrame, *, scene: str,
             kill_at: Sequence[float] = (1 / 3, 2 / 3), run_timeout_s: float = 3600.0,
             transport: str = "pty", say=print) -> SoakResult:
    """Acquire ``scene`` under ``settings``' faults in ``workdir``, SIGKILL it at each
    share of ``kill_at`` complete conditions, resume, ingest, compare with ``reference``."""
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    fault_log = workdir / "faults.log"
    written = soak_params(params, settings, fault_log, scene)
    (workdir / "params.yaml").write_text(yaml.safe_dump(written, sort_keys=False))
    with contextlib.ExitStack() as stack:
        if transport == "socket":
            port = stack.enter_context(socket_board(workdir, scene))
            written["scenes"][scene].update(source="serial", port=port)
            written["acquire"]["indenters"] = "board"
            (workdir / "params.yaml").write_text(yaml.safe_dump(written, sort_keys=False))
        elif transport != "pty":
            raise ValueError(f"transport is pty or socket, not {transport!r}")
        return _soak(written, settings, workdir, reference, scene=scene, kill_at=kill_at,
                     run_timeout_s=run_timeout_s, transport=transport, say=say)


def _soak(written: dict, settings: Soak, workdir: Path, reference: pd.DataFrame, *,
          scene: str, kill_at: Sequence[float], run_timeout_s: float, transport: str,
          say) -> SoakResult:
    fault_log = workdir / "faults.log"
    soaked = validate_params(written, Params, workdir / "params.yaml")
    plan = plan_from_params(scene, soaked.scenes[scene])
    raw_dir = workdir / "data" / "raw" / scene
    log = raw_dir / "acquisition.log"
    started = time.monotonic()
    runs, killed_after = [], []
    for share in [*kill_at, None]:
        target = None if share is None else int(share * len(plan.conditions))
        number = len(runs) + 1
        stderr_path = workdir / f"run{number}.stderr"
        with stderr_path.open("w") as stderr:
            process = subprocess.Popen(
                [sys.executable, "-m", "eskin", "acquire", scene, "--no-progress"],
                cwd=workdir, stdout=subprocess.PIPE, stderr=stderr, text=True)
        deadline = time.monotonic() + run_timeout_s
        if target is not None:
            done = wait_for_conditions(log, target, process, deadline)
            if done is None:
                raise SoakError(f"run {number} ended before {target} conditions were complete:"
                                f" {_tail(stderr_path)}")
            os.kill(process.pid, signal.SIGKILL)
            process.wait()
            killed_after.append(done)
            runs.append(f"SIGKILL with {done} of {len(plan.conditions)} conditions complete")
            say(f"soak: {runs[-1]}")
            continue
        try:
            out, _ = process.communicate(timeout=max(1.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            process.kill()
            raise SoakError(f"run {number} did not finish within {run_timeout_s:g} s") from None
        if process.returncode != 0:
            raise SoakError(f"run {number} failed ({process.returncode}): {_tail(stderr_path)}")
        runs.append(out.strip())
        say(f"soak: {runs[-1]}")
    ingest_at(scene, soaked.scenes[scene], raw_dir, workdir / "data" / "processed",
              ingest=soaked.ingest)
    frame = pd.read_parquet(workdir / "data" / "processed" / f"{scene}.parquet")
    fault_lines = fault_log.read_text().splitlines()
    counted = Counter(line.split("\t", 1)[0] for line in fault_lines)
    asked = [int(m[1]) for line in fault_lines
             if (m := re.fullmatch(r"request\tSAMPLE (\d+)", line))]
    # Asked again because a frame passed its CRC with digits lost (eskin.device.link).
    crc_passed = sum(1 for line in log.read_text(encoding="ascii").splitlines()
                     if line.startswith("X\t") and ("digits lost" in line
                                                    or "board time went backwards" in line))
    return SoakResult(
        scene=scene, conditions=len(plan.conditions), rows_expected=plan.n_samples,
        rows=len(frame), faults={kind: counted.get(kind, 0) for kind in expected_kinds(settings)},
        kills=len(killed_after), killed_after=killed_after,
        **compare(reference, frame, plan), crc_passed=crc_passed,
        seconds=time.monotonic() - started, runs=runs, transport=transport,
        requests=len(asked), frames_requested=sum(asked),
        evidence=differing_evidence(reference, frame, plan, log))


def wait_for_conditions(log: Path, target: int, process: subprocess.Popen,
                         deadline: float) -> int | None:
    """Block until the log holds ``target`` complete conditions (E records); their count,
    or None if the process ended first."""
    seen, offset, tail = 0, 0, b""
    while time.monotonic() < deadline:
        if log.exists():
            with log.open("rb") as handle:
                handle.seek(offset)
                data = tail + handle.read()
            offset += len(data) - len(tail)
            complete, _, tail = data.rpartition(b"\n")
            seen += (b"\n" + complete).count(b"\nE\t") if complete else 0
            if seen >= target:
                return seen
        if process.poll() is not None:
            return None
        time.sleep(0.01)
    process.kill()
    raise SoakError(f"no {target} complete conditions within the time limit")


def _tail(path: Path, lines: int = 5) -> str:
    return " | ".join(path.read_text().strip().splitlines()[-lines:])


def main(argv: Sequence[str] | None = None) -> int:
    """A soak from the command line: params.yaml's settings (the acquisition's defaults
    included), the faults given, against the pipeline's clean dataset of the scene
    (``data/processed/<scene>.parquet``: `dvc checkout` gives it). Writes the result as
    JSON and Markdown to ``--out``; exit 1 if it did not pass."""
    from eskin.catalog import processed_path
    from eskin.config.base import load_params
    from eskin.config.params import Params

    parser = argparse.ArgumentParser(prog="python -m harness.soak", description=main.__doc__)
    parser.add_argument("scene")
    parser.add_argument("--transport", choices=("pty", "socket"), default="pty")
    parser.add_argument("--corrupt", type=float, default=0.0, help="sim_board.corrupt_fraction")
    for kind in ("drop", "garbage", "reset", "stall", "vanish", "ok_dup", "ok_spoof"):
        parser.add_argument(f"--{kind.replace('_', '-')}", type=float, default=0.0,
                            help=f"sim_board.faults.{kind}")
    parser.add_argument("--stall-s", type=float, default=0.3)
    parser.add_argument("--vanish-s", type=float, default=0.05)
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument("--kill-at", type=float, nargs="*", default=[0.33, 0.67])
    parser.add_argument("--workdir", type=Path, required=True, help="scratch directory")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    params = load_params(Params)
    faults = {kind: getattr(args, kind) for kind in
              ("drop", "garbage", "reset", "stall", "vanish", "ok_dup", "ok_spoof")}
    settings = Soak.model_validate({
        "corrupt_fraction": args.corrupt, "kill_at": args.kill_at,
        "timeout_s": params.acquire.timeout_s, "reconnect_s": params.acquire.reconnect_s,
        "faults": {**faults, "stall_s": args.stall_s, "vanish_s": args.vanish_s,
                   "seed": args.seed}})
    reference = pd.read_parquet(processed_path(args.scene))
    result = run_soak(params, settings, args.workdir, reference, scene=args.scene,
                      kill_at=args.kill_at, transport=args.transport)
    args.out.mkdir(parents=True, exist_ok=True)
    stem = args.out / f"{args.scene}-{args.transport}"
    stem.with_suffix(".json").write_text(json.dumps(result.as_dict(), indent=2) + "\n")
    stem.with_suffix(".md").write_text(result.markdown())
    print(result.markdown())
    return 0 if result.passed else 1


if __name__ == "__main__":
    sys.exit(main())
