"""The simulated board's identity is what it does, not its source text (issue 36).

``simulator_identity`` hashes the settings with what a fresh board answers to a fixed
probe: a comment or a refactor keeps every simulated dataset's keys, and so its data;
a change in the physics, or in any setting, re-keys and redraws them.
"""

import builtins
import dataclasses
import io
import json
import os
import pathlib
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import eskin
from eskin.device import board as board_module
from eskin.device import physics
from eskin.device.board import PROBE, SimulatedBoard, probe_answers, simulator_identity
from eskin.device.physics import SkinModel, SkinParams, Trial
from eskin.device.protocol import Frame, parse_line

ROOT = Path(__file__).resolve().parents[1]
REST_MM = 101.0
# The pipeline's skin (params.yaml's sim), as a literal: the probe is checked on it.
SIM = SkinParams(strain_max=0.28, force_half_n=2.0, force_hill=1.0,
                 node_sensitivity_spread=0.2, seating_force_n=3.0, seating_variation=0.5,
                 noise_pf=0.02, drift_offset_pf=0.02)
IDENTITY = re.compile(r"sim-[0-9a-f]{12}")


@pytest.fixture(autouse=True)
def fresh_identities():
    """Every test starts and ends with no identity remembered, so a patched physics
    never leaves its id behind for the next test."""
    board_module._identity.cache_clear()
    yield
    board_module._identity.cache_clear()


def _recompute(params: SkinParams = SIM, rest_length_mm: float = REST_MM) -> str:
    board_module._identity.cache_clear()
    return simulator_identity(params, rest_length_mm)


# ------------------------------------------------------------------ (a) stable


def test_the_identity_is_stable_across_calls_and_processes():
    first = simulator_identity(SIM, REST_MM)
    assert IDENTITY.fullmatch(first)
    assert simulator_identity(SIM, REST_MM) == first      # cached
    assert _recompute() == first                          # worked out again
    code = ("import json, sys\n"
            "from eskin.device.board import simulator_identity\n"
            "from eskin.device.physics import SkinParams\n"
            "print(simulator_identity(SkinParams(**json.loads(sys.argv[1])), 101.0))\n")
    env = {**os.environ, "PYTHONHASHSEED": "random"}
    for _ in range(2):
        done = subprocess.run([sys.executable, "-c", code, json.dumps(SIM.as_dict())],
                              capture_output=True, text=True, check=True, cwd=ROOT, env=env)
        assert done.stdout.strip() == first


def test_the_board_says_its_identity_and_the_probe_is_answered_without_it():
    board = SimulatedBoard(SIM, rest_length_mm=REST_MM)
    hello = parse_line(board.hello().rstrip(b"\n"))
    assert hello.device_id == simulator_identity(SIM, REST_MM)
    assert not any(command.split()[0].upper() == "HELLO" for command in PROBE)
    answers = probe_answers(SIM, REST_MM)
    assert b"#ERR" not in answers and b"#HELLO" not in answers
    frames = [parse_line(line) for line in answers.splitlines() if line.startswith(b"D,")]
    assert all(isinstance(f, Frame) for f in frames) and len(frames) >= 50


def test_an_integer_rest_length_is_the_same_rig():
    assert simulator_identity(SIM, 101) == _recompute(SIM, 101.0)
    assert _recompute(SIM, 101) == simulator_identity(SIM, 101.0)


# ------------------------------------------------------------------ (b) not the source


def test_the_identity_reads_no_file(monkeypatch):
    """The old identity read physics.py and board.py; this one reads nothing."""

    def refuse(*args, **kwargs):
        raise AssertionError(f"the identity opened a file: {args[:1]}")

    other = dataclasses.replace(SIM, seed=SIM.seed + 1)
    with monkeypatch.context() as patch:
        for owner, name in ((pathlib.Path, "read_bytes"), (pathlib.Path, "read_text"),
                            (pathlib.Path, "open"), (builtins, "open"), (io, "open")):
            patch.setattr(owner, name, refuse)
        board_module._identity.cache_clear()
        got = simulator_identity(other, REST_MM)
        again = SimulatedBoard(SIM, rest_length_mm=REST_MM).device_id
    assert IDENTITY.fullmatch(got) and IDENTITY.fullmatch(again) and got != again


def _identity_from_a_copy(tmp_path: Path, edit) -> str:
    """The identity worked out in a fresh process from a copy of the simulator's sources,
    ``edit(name, text)`` applied to each."""
    package = tmp_path / "eskin"
    (package / "device").mkdir(parents=True)
    (package / "__init__.py").write_text(f"__version__ = {eskin.__version__!r}\n")
    (package / "device" / "__init__.py").write_text("")
    for name in ("board.py", "physics.py", "protocol.py"):
        text = (ROOT / "eskin" / "device" / name).read_text()
        edited = edit(name, text)
        (package / "device" / name).write_text(edited)
    code = ("import json, sys\n"
            "import eskin.device.board as board\n"
            "from eskin.device.physics import SkinParams\n"
            "print(board.__file__)\n"
            "print(board.simulator_identity(SkinParams(**json.loads(sys.argv[1])), 101.0))\n")
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    done = subprocess.run([sys.executable, "-c", code, json.dumps(SIM.as_dict())],
                          capture_output=True, text=True, check=True, cwd=tmp_path, env=env)
    where, identity = done.stdout.split()
    assert Path(where).is_relative_to(tmp_path), "the copy was not the one imported"
    return identity


def test_a_comment_and_a_refactor_keep_the_identity(tmp_path):
    def reword(name, text):
        text = text.replace('"""', '"""Reworded. ', 1)          # the module docstring
        if name == "physics.py":
            # A refactor: the same expression, its parts named.
            old = "        return p.strain_max * pressing * ratio / (1 + ratio)\n"
            assert old in text
            text = text.replace(old, "        saturating = ratio / (1 + ratio)\n"
                                     "        return p.strain_max * pressing * saturating\n")
        return text + "\n# An edit to a comment.\n"

    assert _identity_from_a_copy(tmp_path, reword) == simulator_identity(SIM, REST_MM)


def test_a_change_in_the_physics_source_changes_the_identity(tmp_path):
    def soften(name, text):
        if name == "physics.py":
            old = "pressing = min(1.0, (newtons / seat_n) ** (2 / 3))"
            assert old in text
            text = text.replace(old, "pressing = min(1.0, (newtons / seat_n) ** 0.7)")
        return text

    assert _identity_from_a_copy(tmp_path, soften) != simulator_identity(SIM, REST_MM)


# ------------------------------------------------------------------ (c) the settings


def test_a_physics_parameter_changes_the_identity():
    base = simulator_identity(SIM, REST_MM)
    assert _recompute(dataclasses.replace(SIM, noise_pf=0.021)) != base
    assert _recompute(dataclasses.replace(SIM, drift_time_constant_s=301.0)) != base
    assert _recompute(dataclasses.replace(SIM, seed=1)) != base
    assert _recompute() == base


# Each parameter's other value: the probe's answers must show every one of them (not only
# the settings' hash), so the probe reaches whatever that parameter acts through. A new
# parameter needs its entry here.
CHANGED = {
    "seed": 1, "baseline_pf": 20.5, "baseline_spread": 0.06,
    "stretch_sensitivity_spread": 0.04, "strain_max": 0.3, "force_half_n": 2.1,
    "force_hill": 1.1, "stretch_stiffening": 1.6, "reach_nodes": 3,
    "placement_sd_nodes": 0.16, "node_sensitivity_spread": 0.21, "seating_force_n": 3.1,
    "seating_variation": 0.55, "noise_pf": 0.021, "drift_offset_pf": 0.021,
    "drift_time_constant_s": 310.0, "creep_fraction": 0.055, "creep_time_s": 11.0,
    "cav424_ref_pf": 16.2, "cav424_gain_v": 4.1,
    "cav424_gain_spread": 0.06, "cav424_offset_v": 0.51, "supply_v": 5.1, "adc_bits": 11,
}


def test_the_probe_sees_every_parameter():
    fields = {f.name for f in dataclasses.fields(SkinParams)}
    assert set(CHANGED) | {"placement_max_nodes"} == fields
    base = probe_answers(SIM, REST_MM)
    for name, value in CHANGED.items():
        assert probe_answers(dataclasses.replace(SIM, **{name: value}), REST_MM) != base, name
    # The placement clip is reached 3 sd out: seen where it binds often.
    tight = dataclasses.replace(SIM, placement_max_nodes=0.1)
    assert probe_answers(dataclasses.replace(tight, placement_max_nodes=0.12),
                         REST_MM) != probe_answers(tight, REST_MM)


# ------------------------------------------------------------------ (d) the behaviour


def _unclipped_counts(self, capacitance_pf):
    p = self.params
    volts = p.cav424_offset_v + self.cav424_gain_v * (
        capacitance_pf - p.cav424_ref_pf) / p.cav424_ref_pf
    return np.rint(volts / p.supply_v * (2**p.adc_bits - 1)).astype(np.int64)


BEHAVIOURS = {
    # a capacitance off by a hundred-thousandth (0.01 of an ADC count)
    "capacitance": (SkinModel, "capacitance_of_strain", lambda original: lambda self, *a, **k:
                    original(self, *a, **k) * (1 + 1e-5)),
    # a press's strain (only a press shows it)
    "peak_strain": (SkinModel, "peak_strain", lambda original: lambda self, *a, **k:
                    original(self, *a, **k) * 1.01),
    # how far an indenter's strain spreads
    "spread_kernel": (physics, "spread_kernel", lambda original: lambda distance, reach:
                      original(np.asarray(distance) * 1.02, reach)),
    # the indenters land where asked (no placement error, squarely seated)
    "place": (Trial, "place", lambda original: lambda self, x, y, newtons, ramp_s=0.0:
              physics.Indenter(x, y, newtons, placed_s=self.t_s, ramp_s=ramp_s)),
    # the drift 1 % stronger
    "drift": (SkinModel, "drift_pf", lambda original: lambda self, *a, **k:
              original(self, *a, **k) * 1.01),
    # creep and relaxation a tenth faster
    "creep": (Trial, "wait", lambda original: lambda self, seconds, *a:
              original(self, seconds * 1.1, *a)),
    # the CAV424 no longer clipped to its supply (only a full-scale reading shows it)
    "to_counts": (SkinModel, "to_counts", lambda original: _unclipped_counts),
}


@pytest.mark.parametrize("behaviour", sorted(BEHAVIOURS))
def test_a_change_in_behaviour_with_the_same_settings_changes_the_identity(
        monkeypatch, behaviour):
    base = simulator_identity(SIM, REST_MM)
    owner, name, patched = BEHAVIOURS[behaviour]
    monkeypatch.setattr(owner, name, patched(getattr(owner, name)))
    assert _recompute() != base
    monkeypatch.undo()
    assert _recompute() == base


# ------------------------------------------------------------------ (e) the rig


def test_the_rest_length_changes_the_identity():
    base = simulator_identity(SIM, REST_MM)
    assert _recompute(SIM, 100.0) != base
    assert probe_answers(SIM, 100.0) != probe_answers(SIM, REST_MM)  # through STRETCH
