"""The simulated board's command handling, without any transport."""

import numpy as np
import pytest

from eskin.device.board import SimulatedBoard, simulator_identity
from eskin.device.physics import SkinParams
from eskin.device.protocol import Frame, FrameParser, Hello, ParseError, Reply


def events(board, command):
    return FrameParser().feed(board.handle(command.encode()))


def test_hello_announces_protocol_fields():
    hello = events(SimulatedBoard(SkinParams()), "HELLO")[0]
    assert isinstance(hello, Hello)
    assert (hello.terminals, hello.adc_bits) == (20, 10)
    assert hello.device_id.startswith("sim-") and hello.firmware.startswith("sim-")


def test_sample_sends_n_consecutive_frames_then_ok():
    got = events(SimulatedBoard(SkinParams()), "SAMPLE 25")
    frames = [e for e in got if isinstance(e, Frame)]
    assert [f.seq for f in frames] == list(range(25))
    assert got[-1] == Reply(True, "SAMPLE", "25", got[-1].line)
    times = np.diff([f.t_ms for f in frames])
    assert np.all(times == 12)


def test_same_trial_replays_the_same_readings_after_other_work():
    board = SimulatedBoard(SkinParams())
    def trial():
        board.handle(b"SIM CLEAR")
        board.handle(b"SIM TRIAL 99")
        board.handle(b"SIM PRESS 3 3 3.2536")
        return [e.counts for e in events(board, "SAMPLE 20") if isinstance(e, Frame)]
    first = trial()
    board.handle(b"SAMPLE 7")
    assert trial() == first


def test_sim_pick_answers_the_places_named_as_the_first_answer_read_them():
    """Issue 56: a top-up asks for the missing places alone; SIM REPLAY could only ask from
    the first of them on."""
    board = SimulatedBoard(SkinParams())
    board.handle(b"SIM TRIAL 99")
    board.handle(b"SIM PRESS 3 3 3.2536")
    first = [e.counts for e in events(board, "SAMPLE 20") if isinstance(e, Frame)]
    reply = events(board, "SIM PICK 20 3 11 12 19")[0]
    assert isinstance(reply, Reply) and reply.ok and reply.details == "PICK 20 4"
    picked = [e.counts for e in events(board, "SAMPLE 4") if isinstance(e, Frame)]
    assert picked == [first[i] for i in (3, 11, 12, 19)]
    events(board, "SIM PICK 20 1 2")
    refused = events(board, "SAMPLE 3")[-1]  # 3 frames for 2 places named
    assert isinstance(refused, Reply) and not refused.ok and "named 2" in refused.details


def test_the_emulated_rig_picks_as_the_python_board_does():
    from eskin.device.emulated import EmulatedRig
    from eskin.skin import PAPER_SKIN

    rig = EmulatedRig(SkinParams(), skin=PAPER_SKIN, rest_length_mm=101.0, samples=6)
    rig.place(99, [(3, 3, 3.2536)])
    first = [rig.volts(0) for _ in range(6)]
    rig.pick([1, 4])
    assert [rig.volts(0), rig.volts(0)] == [first[1], first[4]]
    rig.replay(4)
    assert [rig.volts(0), rig.volts(0)] == first[4:]


@pytest.mark.parametrize("command, reason", [
    ("SIM PRESS 0 3 1", "outside"), ("SIM PRESS 3 3 nan", "outside"),
    ("STRETCH -1", "outside"), ("STRETCH abc", "not a number"),
    ("SAMPLE 0", "outside"), ("FLY", "unknown"), ("SIM JUMP", "unknown"),
])
def test_bad_commands_get_err_with_a_reason(command, reason):
    reply = events(SimulatedBoard(SkinParams()), command)[0]
    assert isinstance(reply, Reply) and not reply.ok and reason in reply.details


def test_indenter_raises_its_terminals():
    board = SimulatedBoard(SkinParams())
    board.handle(b"SIM TRIAL 1")
    rest = np.mean([e.counts for e in events(board, "SAMPLE 20") if isinstance(e, Frame)], 0)
    board.handle(b"SIM PRESS 2 9 5.2136")
    pressed = np.mean([e.counts for e in events(board, "SAMPLE 20") if isinstance(e, Frame)], 0)
    change = pressed - rest
    assert np.argmax(change[:10]) == 1 and np.argmax(change[10:]) == 8
    assert change[9] < 3 and change[10] < 3, "far terminals feel (almost) nothing"


def test_corruption_hits_about_the_asked_share_and_never_passes_the_parser():
    board = SimulatedBoard(SkinParams(), corrupt_fraction=0.05)
    got = events(board, "SAMPLE 4000")
    frames = [e for e in got if isinstance(e, Frame)]
    assert 0.035 < board.frames_corrupted / 4000 < 0.065
    assert len(frames) == 4000 - board.frames_corrupted
    assert sum(isinstance(e, ParseError) for e in got) >= board.frames_corrupted


def test_identity_follows_every_setting():
    base = simulator_identity(SkinParams(), 101.0)
    assert base == simulator_identity(SkinParams(), 101.0)
    assert base != simulator_identity(SkinParams(noise_pf=0.031), 101.0)
    assert base != simulator_identity(SkinParams(seed=1), 101.0)
    assert base != simulator_identity(SkinParams(), 100.0)


def test_the_papers_skin_reads_byte_for_byte_as_before(repo_params):
    """The paper's skin, with no skin declared, answers exactly what it answered when drift
    and creep went into board time (issue 39; hashes recorded then): skins of other sizes
    leave the default pipeline's raw data, keys and ids alone."""
    import hashlib

    from eskin.device.board import probe_answers

    sim = SkinParams.from_mapping(repo_params["sim"])
    assert hashlib.sha256(probe_answers(sim, 101.0)).hexdigest() == (
        "fb44f877f03052b39582dce43014a404a79644fbbe9abaeaeb9f14f3fde5c1a3")
    assert simulator_identity(sim, 101.0) == "sim-29f9a8acd567"
    board = SimulatedBoard(sim)
    out = board.hello() + b"".join(board.handle(command.encode()) for command in (
        "SIM TRIAL 77", "STRETCH 3.5", "SIM PRESS 2 9 4.5", "SAMPLE 30",
        "SIM PRESS 10 10 50", "SAMPLE 7"))
    assert hashlib.sha256(out).hexdigest() == (
        "c27fc38941cc6743a5ca4db4e866ebc1997c137c7e3246d592aa0a48e406abde")


@pytest.mark.parametrize(("rows", "columns"), [(8, 8), (16, 12), (2, 32)])
def test_a_board_of_any_size_sends_its_terminals_and_refuses_presses_off_its_skin(rows,
                                                                                   columns):
    from eskin.skin import Skin

    skin = Skin(rows, columns)
    board = SimulatedBoard(SkinParams(), skin=skin)
    parser = FrameParser(skin.terminals)
    hello = parser.feed(board.hello())[0]
    assert hello.terminals == rows + columns
    assert hello.device_id != simulator_identity(SkinParams(), 101.0), "its own id"
    assert parser.feed(board.handle(f"SIM PRESS {rows + 1} 1 1".encode()))[0].details == (
        f"{rows + 1} is outside 1..{rows}")
    assert parser.feed(board.handle(f"SIM PRESS 1 {columns + 1} 1".encode()))[0].details == (
        f"{columns + 1} is outside 1..{columns}")
    board.handle(b"SIM TRIAL 1")
    rest = np.mean([e.counts for e in parser.feed(board.handle(b"SAMPLE 20"))
                    if isinstance(e, Frame)], 0)
    board.handle(f"SIM PRESS {rows} {columns} 5.2136".encode())
    frames = [e for e in parser.feed(board.handle(b"SAMPLE 20")) if isinstance(e, Frame)]
    assert len(frames) == 20 and all(len(f.counts) == rows + columns for f in frames)
    change = np.mean([f.counts for f in frames], 0) - rest
    assert np.argmax(change[:rows]) == rows - 1 and np.argmax(change[rows:]) == columns - 1
