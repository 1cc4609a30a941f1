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
