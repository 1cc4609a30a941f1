"""The board's own firmware (firmware/eskin) under simavr, against the Python board.

The firmware does not share a line of code with the Python board (eskin.device.board),
nor the harness with the skin model beyond the voltages it is handed: their answers to
the same commands, and their readings of the same trials, are checked against each other.
`make test` builds both first (`make firmware`).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import serial

from eskin.acquisition.runner import AcquisitionError
from eskin.acquisition.session import acquire_scene
from eskin.data.plan import two_force_plan
from eskin.data.rawlog import LOG_NAME, read_log
from eskin.device.board import FIRMWARE, SimulatedBoard, simulator_identity
from eskin.device.emulated import (
    EMULATED_ID,
    cav424_volts,
    emulated_board,
    firmware_elf,
    harness,
)
from eskin.device.faults import LinkFaults
from eskin.device.link import LinkError
from eskin.device.physics import SkinModel, SkinParams
from eskin.device.protocol import Frame, parse_line
from eskin.skin import PAPER_SKIN, Skin

# Each test here runs the firmware under simavr (often through `eskin`, a process the
# guard does not see): `make check` leaves them out.
pytestmark = pytest.mark.starts

REST_MM = 101.0
EIGHT = Skin(8, 8)  # skins of other sizes, their firmware built by emulated_board
WIDE = Skin(20, 18)  # its x17..x20 and y17, y18 on the third and fourth multiplexers
ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def sim(repo_params):
    for built in (firmware_elf(PAPER_SKIN), harness(PAPER_SKIN)):
        assert built.exists(), f"{built} is missing: `make test` builds it (make firmware)"
    return SkinParams.from_mapping(repo_params["sim"])


@pytest.fixture
def board(sim, request):
    """The emulated board of the paper's skin, or of the skin a test parametrizes."""
    skin = getattr(request, "param", PAPER_SKIN)
    with emulated_board(sim, skin=skin, rest_length_mm=REST_MM, samples=5) as (port, rig):
        # Emulated time runs slower than real time on a busy machine (a 2 s stretch of the
        # clamp took over 10 s once): the deadline is for a board that is gone, not slow.
        link = serial.Serial(port, 115200, timeout=60)
        yield greeted(link), rig
        link.close()


def greeted(link):
    """The link once the board has answered HELLO and the STREAM OFF fence after it, as
    the host greets a board: the greeting sent at boot may be on the wire before the port
    is open, and arrive cut or whole (as from a real Uno)."""
    link.write(b"HELLO\nSTREAM OFF\n")
    lines = []
    while (line := link.readline()) != b"#OK STREAM OFF\n":
        assert line and len(lines) < 3, lines
        lines.append(line)
    assert lines[-1].startswith(b"#HELLO eskin fw-"), lines
    return link


def ask(link, line: bytes) -> bytes:
    link.write(line + b"\n")
    return link.readline()


def test_the_harness_voltage_is_the_models_before_its_adc(sim):
    model = SkinModel(sim)
    capacitance = np.linspace(10.0, 40.0, 20)
    p = sim
    counts = np.rint(np.clip(cav424_volts(model, capacitance), 0, p.supply_v) / p.supply_v
                     * (2**p.adc_bits - 1))
    assert np.array_equal(counts, model.to_counts(capacitance))


def test_the_firmware_answers_bad_commands_as_the_python_board(board, sim):
    link, _ = board
    python = SimulatedBoard(sim)
    lines = [b"BOGUS", b"SAMPLE 0", b"SAMPLE 100001", b"SAMPLE x", b"STRETCH 41",
             b"STRETCH abc", b"STREAM MAYBE", b"STRETCH 2.5", b"x" * 300]
    for line in lines:
        assert ask(link, line) == python.handle(line), line
    # SIM belongs to the simulated board: here a person places the weights
    assert ask(link, b"SIM PRESS 1 1 1").startswith(b"#ERR SIM ")


def test_streaming_goes_on_while_commands_are_answered(board):
    link, _ = board
    link.write(b"STREAM ON\n")
    assert link.readline() == b"#OK STREAM ON\n"
    link.write(b"HELLO\n")
    seen, frames = [], 0
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline and not (seen and frames >= 6):
        event = parse_line(link.readline().rstrip(b"\n"))
        if isinstance(event, Frame):
            frames += 1
        else:
            seen.append(event)
    assert frames >= 6 and any(type(e).__name__ == "Hello" for e in seen), (frames, seen)
    link.write(b"STREAM OFF\n")
    while (line := link.readline()) != b"#OK STREAM OFF\n":
        assert line.startswith(b"D,"), line  # frames already on their way, then the #OK
    link.timeout = 0.5
    assert link.readline() == b""  # and no more


def emulated_and_python_frames(link, rig, sim, conditions, samples):
    """Each (mm, trial, contacts) on both boards of the rig's skin: their frames' counts,
    (frames, terminals) each."""
    python = SimulatedBoard(sim, skin=rig.model.skin)
    ours, theirs = [], []
    for mm, trial, contacts in conditions:
        for command in (f"STRETCH {mm}", "SIM CLEAR", f"SIM TRIAL {trial}",
                        *(f"SIM PRESS {x} {y} {n!r}" for x, y, n in contacts)):
            python.handle(command.encode())
        answer = python.handle(b"SAMPLE %d" % samples)
        theirs += [parse_line(line).counts for line in answer.splitlines()
                   if line.startswith(b"D,")]
        assert ask(link, f"STRETCH {mm}".encode()) == f"#OK STRETCH {mm}\n".encode()
        rig.place(trial, contacts)
        link.write(b"SAMPLE %d\n" % samples)
        seqs = []
        while isinstance(event := parse_line(link.readline().rstrip(b"\n")), Frame):
            ours.append(event.counts)
            seqs.append(event.seq)
        assert event.line == b"#OK SAMPLE %d" % samples, event
        assert seqs == list(range(seqs[0], seqs[0] + samples))  # CRC-checked, in order
    return np.array(ours), np.array(theirs)


@pytest.mark.parametrize("board", [PAPER_SKIN, EIGHT, WIDE], ids=["10x10", "8x8", "20x18"],
                         indirect=True)
def test_the_firmware_reads_what_the_python_board_sends_for_the_same_trials(board, sim):
    """On the paper's skin and on others, each firmware built for its own skin: the
    presses on the last row and column reach the terminals of the third and fourth
    multiplexers on the 20 × 18."""
    link, rig = board
    skin = rig.model.skin
    conditions = [("0.000", 9, []), ("7.999", 5, [(3, 4, 3.2536)]),
                  ("15.998", 11, [(skin.rows, 1, 5.2136), (1, skin.columns, 1.2936)]),
                  ("0.000", 12, [(6, 6, 1.2936)])]
    ours, theirs = emulated_and_python_frames(link, rig, sim, conditions, samples=5)
    assert ours.shape == theirs.shape == (20, skin.terminals)
    hello = parse_line(ask(link, b"HELLO").rstrip(b"\n"))
    assert hello.terminals == skin.terminals
    assert hello.firmware == ("fw-1.0.0" if skin == PAPER_SKIN
                              else f"fw-1.0.0+{skin.rows}x{skin.columns}")
    differ = ours != theirs
    # A voltage reaches simavr in 1/64 of an ADC step: within that of a transition a
    # reading may round the other way (module docstring of eskin.device.emulated).
    assert np.abs(ours - theirs).max() <= 1
    assert differ.mean() < 0.03, differ.mean()


def test_a_scene_acquired_from_the_firmware_matches_the_python_boards(sim, tmp_path):
    """The unchanged host code (run_session) on both boards, a small two-force plan
    recorded twice (``repeats``: each repetition a new trial, on both boards alike)."""
    plan = two_force_plan("pairs", [1.0], [1.2936, 5.2136], [1, 10], [1, 10], samples=4,
                          repeats=2)
    logs = {}
    for source in ("emulated", "simulated"):
        report = acquire_scene(plan, tmp_path / source, source=source, sim=sim,
                               rest_length_mm=REST_MM, progress=False)
        assert report.frames_rejected == 0
        logs[source] = read_log(tmp_path / source / LOG_NAME)
    emulated, simulated = logs["emulated"], logs["simulated"]
    device = emulated.sessions[0]["device"]
    assert emulated.sessions[0]["source"] == "emulated"
    assert device["firmware"].startswith("fw-") and device["id"] == EMULATED_ID
    sim_id = simulator_identity(sim, REST_MM)
    differ = []
    for condition in plan.conditions:
        ours = emulated.completed[condition.key(device["id"], device["firmware"])].frames
        theirs = simulated.completed[condition.key(sim_id, FIRMWARE)].frames
        a = np.array([f.counts for f in ours])
        b = np.array([f.counts for f in theirs])
        assert a.shape == b.shape == (plan.samples, 20)
        assert np.abs(a - b).max() <= 1, condition
        differ.append((a != b).mean())
    assert np.mean(differ) < 0.03
    once = len(plan.conditions) // 2
    for first, again in zip(plan.conditions[:once], plan.conditions[once:], strict=True):
        assert (first.repeat, again.repeat) == (0, 1) and first.contacts == again.contacts
        a, b = (np.array([f.counts for f in emulated.completed[c.key(
            device["id"], device["firmware"])].frames]) for c in (first, again))
        assert (a != b).any(), f"repetition 2 of {first.describe()} read as its first"


def test_link_faults_mid_request_cost_nothing(sim, tmp_path):
    """The firmware resets as scans 3 and 30 begin (the host opening the Uno's port does
    that too); then, in another run, the USB link vanishes there for 0.3 s and comes back
    on a new pty, followed by the port's link. The host notices, reconnects, asks again,
    and the dataset is the clean one. Scan 30 is on the stretched skin (6 conditions × 4
    scans unstretched first): the clamp's position survives the reset (the firmware keeps
    it in .noinit RAM), so the stretch the skin sees stays right."""
    plan = two_force_plan("pairs", [1.0, 1.07921], [5.2136], [1, 10], [1, 10], samples=4)
    frames = {}
    for kind in ("clean", "reset", "vanish"):
        faults = {} if kind == "clean" else {3: kind, 30: kind}
        report = acquire_scene(plan, tmp_path / kind, source="emulated", sim=sim,
                               rest_length_mm=REST_MM, progress=False, emulated_faults=faults,
                               faults=LinkFaults(vanish_s=0.3))
        # At least one recovery a fault: on a loaded machine simavr can fall behind the
        # host's timeout, which costs a reconnect more (even in the clean run, once in
        # CI); what must hold whatever the load is the dataset, compared below.
        if kind == "vanish":  # the port hangs up: the host reopens it at the same path
            assert report.reconnects >= len(faults), report
        elif kind == "reset":
            # A reset cuts the line on the wire short, and the greeting after it is lost
            # with it as often as not: then the host times out and reconnects instead.
            assert report.resets + report.reconnects >= len(faults), report
        log = read_log(tmp_path / kind / LOG_NAME)
        assert len(log.completed) == len(plan.conditions)
        frames[kind] = {key: [f.counts for f in attempt.frames]
                        for key, attempt in log.completed.items()}
    assert frames["reset"] == frames["clean"]
    assert frames["vanish"] == frames["clean"]


def test_a_failing_rig_is_named_in_the_hosts_error(sim, tmp_path, monkeypatch):
    """If the Python side of the harness fails, the host loses the board; its one-line
    error says why, and the conditions already recorded are kept. The second condition's
    frames all came, but a condition is recorded only once the frame after its last one
    has judged that frame's board time (docs/acquisition.md), and that frame, the third
    condition's first, never came: its frames are in the log, its attempt abandoned."""
    from eskin.device.emulated import EmulatedRig

    answer = EmulatedRig.answer

    def failing(self, question):
        if self._scans >= 9:  # two conditions of 4 scans in, the third's first scan fails
            raise RuntimeError("the skin model broke")
        return answer(self, question)

    monkeypatch.setattr(EmulatedRig, "answer", failing)
    plan = two_force_plan("pairs", [1.0], [5.2136], [1, 10], [1, 10], samples=4)
    with pytest.raises(LinkError, match="The emulated rig had failed: RuntimeError: the "
                       "skin model broke"):
        acquire_scene(plan, tmp_path, source="emulated", sim=sim, rest_length_mm=REST_MM,
                      progress=False, timeout_s=1.0, max_attempts=1, reconnect_s=1.0)
    log = read_log(tmp_path / LOG_NAME)
    first, second = (c.key(EMULATED_ID, log.sessions[-1]["device"]["firmware"])
                     for c in plan.conditions[:2])
    assert list(log.completed) == [first]
    lines = (tmp_path / LOG_NAME).read_text().splitlines()
    attempt = next(line.split("\t")[1] for line in lines
                   if line.startswith("B\t") and f'"key": "{second}"' in line)
    assert sum(line.startswith(f"F\t{attempt}\t") for line in lines) == 4
    assert any(line.startswith(f"X\t{attempt}\t") and "judged that frame's board time" in line
               for line in lines), "the held condition's attempt is closed, saying why"


@pytest.mark.parametrize("skin", [None, {"rows": 16, "columns": 12}], ids=["paper", "16x12"])
def test_a_scene_of_params_yaml_is_acquired_from_the_firmware(small_params, tmp_path, skin):
    """``source: emulated`` (here ``eskin acquire --source emulated``) acquires a scene from
    the firmware built for the scene's skin through the unchanged host code, and ingest
    makes a dataset of it, with that skin's channels."""
    from eskin.data.schema import read_metadata
    from tests.conftest import write_params

    rows, columns = (10, 10) if skin is None else (skin["rows"], skin["columns"])
    # pairs only (the paper's plan): the emulator's time goes to what this test is about
    small_params["scenes"]["two_force"].update(
        forces=[5.2136], nodes_x=[1, rows], nodes_y=[1, columns], samples=4,
        contact_counts=[2])
    if skin is not None:
        small_params["scenes"]["two_force"]["skin"] = skin
    small_params["cv"]["folds"] = 2
    write_params(tmp_path, small_params)
    for command in (["acquire", "two_force", "--source", "emulated", "--no-progress"],
                    ["ingest", "two_force"]):
        done = subprocess.run([sys.executable, "-m", "eskin", *command], cwd=tmp_path,
                              capture_output=True, text=True, timeout=300,
                              env={**os.environ, "PYTHONPATH": str(ROOT)})
        assert done.returncode == 0, done.stderr
    log = read_log(tmp_path / "data/raw/two_force" / LOG_NAME)
    assert log.sessions[-1]["simulator"]["emulated"] is True
    path = tmp_path / "data/processed/two_force.parquet"
    data = pd.read_parquet(path)
    assert len(data) == 6 * 4  # 6 pairs of the 4 corner nodes, 4 samples each
    assert [c for c in data.columns if c[:2] in ("cx", "cy")] == (
        [f"cx{i}" for i in range(1, rows + 1)] + [f"cy{i}" for i in range(1, columns + 1)])
    assert read_metadata(path).get("skin") == skin  # recorded when not the paper's
    device = log.sessions[-1]["device"]
    assert device["terminals"] == rows + columns and device["firmware"].startswith("fw-")


def test_a_board_without_an_id_is_given_one_once_and_refused_before(sim, tmp_path):
    """A new board says id=unset, which any other new board shares: acquisition from a
    port refuses it, saying how to give it one; `eskin device set-id` does, once."""
    plan = two_force_plan("pairs", [1.0], [5.2136], [1, 10], [1, 10], samples=4)
    with emulated_board(sim, skin=PAPER_SKIN, rest_length_mm=REST_MM,
                        samples=4) as (port, _rig):
        with pytest.raises(AcquisitionError, match=f"the board on {port} has no device id "
                           f"\\(id=unset\\): give it one, once: eskin device set-id {port} <id>"):
            acquire_scene(plan, tmp_path, source="serial", port=port, sim=sim,
                          rest_length_mm=REST_MM, progress=False, indenters="board")
        command = [sys.executable, "-m", "eskin", "device", "set-id", port, "lab2-skin1"]
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        done = subprocess.run(command, capture_output=True, text=True, timeout=60, env=env)
        assert done.returncode == 0, done.stderr
        assert done.stdout.startswith(f"the board on {port} is now lab2-skin1 (firmware fw-")
        again = subprocess.run([*command[:-1], "lab2-skin2"], capture_output=True, text=True,
                               timeout=60, env=env)
        assert again.returncode == 1
        assert again.stderr.strip().endswith(
            f"the board on {port} already has the id 'lab2-skin1': an id is set once")


def test_the_firmware_header_maps_each_terminal_to_its_multiplexer():
    """x1..x16 and y1..y16 on multiplexers 0 and 1, x17.. and y17.. on 2 and 3; only the
    multiplexers a skin uses are driven; the paper's firmware keeps its name."""
    from eskin.device.firmware import FirmwareSkinError, firmware_tag, skin_header, terminal_map
    from eskin.skin import ChannelArray

    mapping = terminal_map(WIDE)
    assert mapping[:2] == [(0, 0), (0, 1)] and mapping[15:17] == [(0, 15), (2, 0)]
    assert mapping[20:22] == [(1, 0), (1, 1)] and mapping[36:] == [(3, 0), (3, 1)]
    assert "#define MULTIPLEXERS_USED 0xf" in skin_header(WIDE)
    paper = skin_header(PAPER_SKIN)
    assert "#define TERMINALS 20" in paper and "#define MULTIPLEXERS_USED 0x3" in paper
    assert (firmware_tag(PAPER_SKIN), firmware_tag(EIGHT)) == ("", "+8x8")
    with pytest.raises(FirmwareSkinError, match="the firmware reads a row/column skin"):
        skin_header(ChannelArray(("a", "b"), 2, 2))


def test_a_firmware_beyond_32_rows_is_refused_in_one_line():
    done = subprocess.run(["make", "-s", "-C", str(ROOT / "firmware/eskin"), "ROWS=40",
                           "COLUMNS=8", f"PYTHON={sys.executable}"], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode != 0
    assert "firmware for ROWS=40 COLUMNS=8: a skin has 2 to 32 rows, got 40" in done.stderr
    assert not (ROOT / "firmware/eskin/build/40x8/eskin.elf").exists()
