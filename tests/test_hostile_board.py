"""Hostile boards, operators and configs (issue 18): each finding, kept as a test.

The board is ``tests/hostile_board.py``, an independent implementation of
protocol v1 that imports nothing from eskin. Every case ends in the clean
dataset (row by row equal to an honest run's) or in a one-line error, exit
code 1, within the timeout and reconnect budget.
"""

import copy
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import eskin, small_scenes, write_params
from hostile_board import HostileBoard, Served, damaged, frame_line

from eskin.acquisition.runner import AcquisitionError, OperatorPlacer, SimulatedPlacer
from eskin.acquisition.session import run_session
from eskin.config.base import validate_params
from eskin.config.params import Params
from eskin.data.plan import plan_from_params
from eskin.data.rawlog import MAGIC, read_log
from eskin.data.schema import LABELS
from eskin.device.host import (
    Answered,
    Greeted,
    HostProtocol,
    Junk,
    OtherBoard,
    OtherSkin,
    Restarted,
    SampleComplete,
    SampleFrame,
    SampleIncomplete,
    Stray,
    TimeJumped,
    Violation,
)
from eskin.skin import PAPER_SKIN
from eskin.steps.ingest import ingest_log

PAPER_CHANNELS = PAPER_SKIN.channels  # the scenes of these tests are on the paper's skin
CONTENT = ["trial", "sample", *PAPER_CHANNELS, *LABELS["single_force"]]
TIMEOUT_S, RECONNECT_S = 0.5, 2.0


# One stretch, and not the rest length: a board that forgot it reads every condition wrong.
STRETCHES = [1.07921]
CONDITIONS = len(STRETCHES) * 2 * 101  # × the small scene's 2 forces × 101 nodes (0 too)


def hostile_params(repo_params):
    params = small_scenes(repo_params)
    params["scenes"]["single_force"]["stretches"] = list(STRETCHES)
    params["acquire"].update(timeout_s=TIMEOUT_S, reconnect_s=RECONNECT_S)
    return params


def acquire_from(board, tmp_path, params, transport="pty", placer=None,
                 timeout_s=TIMEOUT_S):
    plan = plan_from_params("single_force", validate_params(params, Params).scenes["single_force"])
    with Served(board, transport) as served:
        report = run_session(plan, tmp_path, port=served.port,
                             placer=placer or SimulatedPlacer(),
                             rest_length_mm=101.0, simulator=None, timeout_s=timeout_s,
                             reconnect_s=RECONNECT_S, progress=False)
    return report, plan


@pytest.fixture(scope="module")
def honest(tmp_path_factory, repo_params):
    params = hostile_params(repo_params)
    root = tmp_path_factory.mktemp("honest")
    _, plan = acquire_from(HostileBoard(), root, params)
    return params, ingest_log(root / "acquisition.log", plan).frame


# ---------------------------------------------------------------- the state machine alone

def greeted(device="b1"):
    host = HostProtocol()
    host.send_greeting()
    events = host.receive(f"#HELLO eskin fw terminals=20 adc_bits=10 id={device}\n"
                          "#OK STREAM OFF\n".encode())
    assert isinstance(events[-1], Greeted)
    return host


def frames(first, n):
    return b"".join(frame_line(first + i, 12 * (first + i), [500] * 20) for i in range(n))


def test_protocol_credits_exactly_n_frames_then_ok_to_the_request():
    host = greeted()
    host.send_sample(3)
    events = host.receive(frames(0, 3) + b"#OK SAMPLE 3\n")
    assert [type(e) for e in events] == [SampleFrame] * 3 + [SampleComplete]
    assert {e.request for e in events} == {2}


def test_protocol_sequence_runs_across_requests_so_a_replay_is_a_violation():
    host = greeted()
    host.send_sample(3)
    host.receive(frames(0, 3) + b"#OK SAMPLE 3\n")
    host.send_sample(3)
    events = host.receive(frames(0, 3) + frames(3, 3) + b"#OK SAMPLE 3\n")
    assert isinstance(events[0], Violation) and "backwards" in events[0].reason
    assert not any(isinstance(e, SampleFrame) for e in events), "nothing credited"
    assert host.needs_fence


def test_protocol_an_early_ok_leaves_places_empty_and_an_extra_frame_is_a_violation():
    host = greeted()
    host.send_sample(3)
    events = host.receive(frames(0, 2) + b"#OK SAMPLE 3\n" + frames(2, 1))
    assert [type(e) for e in events] == [SampleFrame, SampleFrame, SampleIncomplete, Stray]
    assert events[2] == SampleIncomplete(2, 2, 3), "the late frame belongs to no request"
    assert host.needs_fence, "a short answer is fenced: its #OK may not have been the answer's"
    host.send_fence()
    host.receive(b"#OK STREAM OFF\n")
    host.send_sample(3)
    events = host.receive(frames(3, 4) + b"#OK SAMPLE 3\n")
    assert isinstance(events[3], Violation) and "more than the 3" in events[3].reason


def test_protocol_a_frame_owed_after_an_early_ok_is_never_the_next_answers():
    host = greeted()
    host.send_sample(3)
    host.receive(frames(0, 2) + b"#OK SAMPLE 3\n")
    host.send_sample(3)
    events = host.receive(frames(2, 3) + b"#OK SAMPLE 3\n")
    assert isinstance(events[0], Stray), "seq 2 is owed to the first request"
    assert [(e.index, e.frame.seq) for e in events if isinstance(e, SampleFrame)] == [
        (0, 3), (1, 4)]
    assert events[-1] == SampleIncomplete(3, 2, 3)


def test_protocol_places_each_frame_by_its_seq_so_an_answer_keeps_what_came():
    """The top-up (issue 40): a frame lost mid-answer no longer closes the request, so the
    frames after it are credited, each at the place its seq gives it, and the answer ends
    SampleIncomplete; old code: a Violation at the gap, and every frame after it stray."""
    host = greeted()
    host.send_sample(2)
    host.receive(frames(0, 2) + b"#OK SAMPLE 2\n")
    host.send_sample(6)  # places 1 and 4 damaged on the line
    events = host.receive(frames(2, 1) + damaged(frame_line(3, 36, [500] * 20))
                          + frames(4, 2) + damaged(frame_line(6, 72, [500] * 20))
                          + frames(7, 1) + b"#OK SAMPLE 6\n")
    credited = [e for e in events if isinstance(e, SampleFrame)]
    assert [(e.index, e.frame.seq, e.placed) for e in credited] == [
        (0, 2, True), (2, 4, True), (3, 5, True), (5, 7, True)]
    assert events[-1] == SampleIncomplete(3, 4, 6) and host.needs_fence
    host.send_fence()  # absorbs nothing: the seq the next answer begins at stays known
    host.receive(b"#OK STREAM OFF\n")
    host.send_sample(2)  # the next answer's places start after the whole of that one
    events = host.receive(frames(8, 2) + b"#OK SAMPLE 2\n")
    assert [e.index for e in events if isinstance(e, SampleFrame)] == [0, 1]
    assert isinstance(events[-1], SampleComplete)
    host.send_sample(4)  # a restart mid-answer: what came before it keeps its places
    events = host.receive(frames(10, 1) + damaged(frame_line(11, 132, [500] * 20))
                          + frames(12, 1) + b"#HELLO eskin fw terminals=20 adc_bits=10 id=b1\n")
    assert [(e.index, e.placed) for e in events if isinstance(e, SampleFrame)] == [
        (0, True), (2, True)]
    assert isinstance(events[-1], Restarted)
    host.send_fence()
    host.receive(b"#OK STREAM OFF\n")
    host.send_sample(5)  # no seq since the #HELLO, a damaged line first: not placed
    events = host.receive(damaged(frame_line(0, 0, [500] * 20)) + frames(1, 1)
                          + damaged(frame_line(2, 24, [500] * 20)) + frames(3, 1)
                          + damaged(frame_line(4, 48, [500] * 20)) + b"#OK SAMPLE 5\n")
    assert [(e.index, e.placed) for e in events if isinstance(e, SampleFrame)] == [
        (0, False), (2, False)]
    assert events[-1] == SampleIncomplete(8, 2, 5)
    # Its last frame was lost too, so where the board's count stands is unknown: the next
    # answer begins at its first frame (seq 4 did not arrive: 5 is the answer's first).
    host.send_sample(3)
    events = host.receive(frames(5, 3) + b"#OK SAMPLE 3\n")
    assert [(e.index, e.placed) for e in events if isinstance(e, SampleFrame)] == [
        (0, True), (1, True), (2, True)]
    assert isinstance(events[-1], SampleComplete)


def test_protocol_frames_outside_a_request_are_stray_and_a_wrong_count_is_a_violation():
    host = greeted()
    assert all(isinstance(e, Stray) for e in host.receive(frames(0, 5)))
    host.send_sample(2)
    events = host.receive(frames(5, 2) + b"#OK SAMPLE 3\n")
    assert isinstance(events[-1], Violation)


def test_protocol_tells_a_restart_from_another_board():
    host = greeted("b1")
    host.send_sample(4)
    events = host.receive(frames(0, 2) + b"#HELLO eskin fw terminals=20 adc_bits=10 id=b1\n")
    assert isinstance(events[-1], Restarted)
    host.send_sample(4)
    events = host.receive(frames(0, 1) + b"#HELLO eskin fw terminals=20 adc_bits=10 id=b2\n"
                          + frames(0, 3) + b"#OK SAMPLE 4\n")
    assert isinstance(events[1], OtherBoard) and events[1].expected == "b1"
    assert [type(e) for e in events[2:]] == [Stray] * 3, "nothing of b2 is credited"


def test_protocol_refuses_a_board_of_other_terminals_than_the_skin_it_reads():
    """A host reading the paper's skin (20 terminals) greets a 16-terminal board: the
    greeting ends in OtherSkin, and that board's frames never parse as the skin's."""
    host = HostProtocol(terminals=20)
    host.send_greeting()
    events = host.receive(b"#HELLO eskin fw terminals=16 adc_bits=10 id=b8\n#OK STREAM OFF\n")
    assert [type(e) for e in events] == [OtherSkin]
    assert (events[0].hello.terminals, events[0].expected) == (16, 20)
    narrow = b"".join(frame_line(i, 12 * i, [500] * 16) for i in range(2))
    assert all(isinstance(e, Junk) and "expected 22" in e.error.reason
               for e in host.receive(narrow))


def test_protocol_a_damaged_first_frame_with_no_seq_to_place_it_costs_one_retry():
    """Issue 40, finding 1: after a connect (or a #HELLO) the host has no seq to compare
    with. A damaged first frame made it owe the seq after the answer's last frame, so
    every later clean answer lost its first frame as owed and came up one short. The
    frames after it cannot be placed (the damaged line may have been the first)."""
    host = greeted()
    host.send_sample(5)
    events = host.receive(damaged(frame_line(0, 0, [500] * 20)) + frames(1, 4)
                          + b"#OK SAMPLE 5\n")
    assert isinstance(events[0], Junk) and isinstance(events[-1], SampleIncomplete)
    assert not any(e.placed for e in events if isinstance(e, SampleFrame))
    host.send_sample(5)
    events = host.receive(frames(5, 5) + b"#OK SAMPLE 5\n")
    assert [type(e) for e in events] == [SampleFrame] * 5 + [SampleComplete], events
    # The same after a restart, whose #HELLO starts the board's sequence again.
    host.send_sample(5)
    events = host.receive(b"#HELLO eskin fw terminals=20 adc_bits=10 id=b1\n")
    assert isinstance(events[-1], Restarted)
    host.send_fence()
    host.receive(b"#OK STREAM OFF\n")
    host.send_sample(2)
    host.receive(damaged(frame_line(0, 0, [500] * 20)) + frames(1, 1) + b"#OK SAMPLE 2\n")
    host.send_sample(2)
    events = host.receive(frames(2, 2) + b"#OK SAMPLE 2\n")
    assert [type(e) for e in events] == [SampleFrame] * 2 + [SampleComplete], events


def test_protocol_a_lost_frame_of_one_answer_is_never_the_next_answers_loss():
    """Issue 40, finding 2: the next clean answer failed with "frames lost: expected seq
    N, got N+1" for a frame the answer before had lost (its last): a wasted retry."""
    host = greeted()
    host.send_sample(3)
    host.receive(frames(0, 3) + b"#OK SAMPLE 3\n")
    host.send_sample(3)  # its last frame damaged
    events = host.receive(frames(3, 2) + damaged(frame_line(5, 60, [500] * 20))
                          + b"#OK SAMPLE 3\n")
    assert events[-1] == SampleIncomplete(3, 2, 3)
    host.send_sample(3)
    events = host.receive(frames(6, 3) + b"#OK SAMPLE 3\n")
    assert [type(e) for e in events] == [SampleFrame] * 3 + [SampleComplete], events
    host.send_sample(5)  # frames lost mid-answer and last
    events = host.receive(frames(9, 1) + damaged(frame_line(10, 120, [500] * 20))
                          + frames(11, 2) + damaged(frame_line(13, 156, [500] * 20))
                          + b"#OK SAMPLE 5\n")
    assert [e.index for e in events if isinstance(e, SampleFrame)] == [0, 2, 3]
    host.send_sample(3)
    events = host.receive(frames(14, 3) + b"#OK SAMPLE 3\n")
    assert [type(e) for e in events] == [SampleFrame] * 3 + [SampleComplete], events


# ---------------------------------------------------------------- findings 1-3, end to end

@pytest.mark.parametrize("transport", ["pty", "socket"])
@pytest.mark.parametrize("misbehaviour", ["replay", "early_ok", "extra_frame",
                                          "restart_after_ok"])
def test_a_board_that_answers_out_of_turn_still_gives_the_clean_dataset(
        honest, tmp_path, misbehaviour, transport):
    params, clean = honest
    report, plan = acquire_from(HostileBoard(misbehaviour=misbehaviour), tmp_path, params,
                                transport)
    assert report.retries + report.resets >= 1, report.summary()
    frame = ingest_log(tmp_path / "acquisition.log", plan).frame
    pd.testing.assert_frame_equal(frame[CONTENT], clean[CONTENT])


@pytest.mark.parametrize("transport", ["pty", "socket"])
def test_another_board_mid_request_stops_and_none_of_its_frames_is_stored(
        honest, tmp_path, transport):
    params, clean = honest
    with pytest.raises(AcquisitionError, match="another board answered .*id OTHER-9999, "
                       "expected hostile-0001"):
        acquire_from(HostileBoard(misbehaviour="other_board", at=50), tmp_path, params,
                     transport)
    contents = read_log(tmp_path / "acquisition.log")
    assert len(contents.completed) == 49
    stored = {key: [f.counts for f in a.frames] for key, a in contents.completed.items()}
    for key, rows in stored.items():
        assert all(777 not in counts for counts in rows)
        expected = clean[clean["trial"] == key][PAPER_CHANNELS].to_numpy().tolist()
        assert [list(map(float, r)) for r in rows] == expected


def high_water_mb(pid: int) -> float | None:
    """VmHWM of a live process: its own peak since exec (rusage's ru_maxrss would
    include the test process, copied into the child by fork before the exec)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return None
    kib = next((int(line.split()[1]) for line in status.splitlines()
                if line.startswith("VmHWM:")), None)
    return kib / 1024 if kib is not None else None


def run_cli_against(board, root, params, transport="pty"):
    """`eskin acquire` in its own process against ``board``: (exit code, stderr, seconds,
    the process's own peak memory in MB)."""
    params = copy.deepcopy(params)
    with Served(board, transport) as served:
        params["acquire"]["indenters"] = "board"
        params["scenes"]["single_force"].update(source="serial", port=served.port)
        write_params(root, params)
        started = time.monotonic()
        child = subprocess.Popen([sys.executable, "-m", "eskin", "acquire", "single_force",
                                  "--no-progress"], cwd=root, stdin=subprocess.DEVNULL,
                                 stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        peak = 0.0
        while child.poll() is None:  # VmHWM only grows: the last reading is the peak
            peak = max(peak, high_water_mb(child.pid) or 0.0)
            if time.monotonic() - started > 120:
                child.kill()  # a hang fails the test, never blocks the suite
            time.sleep(0.02)
        return child.returncode, child.stderr.read(), time.monotonic() - started, peak


@pytest.mark.parametrize("misbehaviour", ["trickle", "flood"])
@pytest.mark.heavy
def test_a_board_that_never_answers_ends_within_the_budget_in_bounded_memory(
        honest, tmp_path, misbehaviour):
    params, _ = honest
    code, stderr, seconds, peak_mb = run_cli_against(
        HostileBoard(misbehaviour=misbehaviour, at=30), tmp_path, params)
    assert code == 1, stderr
    lines = [line for line in stderr.splitlines() if line.startswith("eskin: error")]
    assert len(lines) == 1 and "lost the board" in lines[0] and "Traceback" not in stderr
    # Each wait is bounded: the request's timeout, then the reconnect budget (+ start-up).
    assert seconds < 2 * TIMEOUT_S + RECONNECT_S + 8, seconds
    # The process's own peak: start-up (pandas, pyarrow, pydantic) is about 130 MB.
    assert peak_mb < 250, f"{peak_mb:.0f} MB"
    contents = read_log(tmp_path / "data" / "raw" / "single_force" / "acquisition.log")
    # The 29th condition's last frame awaits the board's next frame to judge its time
    # (issue 56): the flood's frames do, the trickle sends none, so it is asked again.
    assert len(contents.completed) == (29 if misbehaviour == "flood" else 28), \
        "what arrived before is kept"


@pytest.mark.parametrize("transport", ["pty", "socket"])
def test_a_board_that_lags_by_a_frame_is_given_up_on_never_stored_shifted(
        honest, tmp_path, transport):
    """The early #OK of finding 2, kept up: each answer n frames long, shifted by one."""
    params, clean = honest
    with pytest.raises(AcquisitionError, match=r"failed 5 times .*\(4 of its 5 frames "
                       r"arrived valid\), last: 0 of 1 frames arrived"):
        acquire_from(HostileBoard(misbehaviour="lagging", at=50), tmp_path, params, transport)
    contents = read_log(tmp_path / "acquisition.log")
    assert len(contents.completed) == 49
    for key, attempt in contents.completed.items():
        expected = clean[clean["trial"] == key][PAPER_CHANNELS].to_numpy().tolist()
        assert [list(map(float, f.counts)) for f in attempt.frames] == expected


# ---------------------------------------------------------------- issue 40, end to end

@pytest.mark.parametrize(("misbehaviour", "retries", "resets", "reconnects"), [
    (None, 1, 0, 0),                 # the first answer after the connect
    # ... and after the board's restart, whose #HELLO came before anything judged the
    # answer's last frame's time: that place is asked again too (issue 56)
    ("restart_after_ok", 4, 1, 0),
    ("silent", 3, 0, 1),             # ... and after the reconnect its silence caused
])
def test_a_damaged_first_frame_after_a_greeting_costs_one_retry(
        honest, tmp_path, misbehaviour, retries, resets, reconnects):
    """Finding 1: with no seq to place the answer by, its damaged first frame used to cost
    every attempt after it (`failed 5 times ... #OK SAMPLE after 4 of 5`)."""
    params, clean = honest
    report, plan = acquire_from(HostileBoard(misbehaviour=misbehaviour, damage_first=True),
                                tmp_path, params)
    assert (report.retries, report.resets, report.reconnects) == (
        retries, resets, reconnects), report.summary()
    frame = ingest_log(tmp_path / "acquisition.log", plan).frame
    pd.testing.assert_frame_equal(frame[CONTENT], clean[CONTENT])


def test_a_restart_after_the_last_conditions_answer_gets_the_stretch_again(
        honest, tmp_path):
    """The plan's last condition, stretched, answered whole; then the board restarts
    (stretch and presses forgotten) in place of the one frame asked to judge the answer's
    last frame. That condition is asked again, and its board must be stretched again: a
    soak once stored a frame read at rest for it (the restart seen only by the judging
    request, which dropped the news; the CI soak of ca3f7da, 1 sample of 2,020)."""
    params, clean = honest
    last = len(plan_from_params(
        "single_force", validate_params(params, Params).scenes["single_force"]).conditions)
    report, plan = acquire_from(HostileBoard(misbehaviour="restart_mid", at=last + 1),
                                tmp_path, params)
    frame = ingest_log(tmp_path / "acquisition.log", plan).frame
    pd.testing.assert_frame_equal(frame[CONTENT], clean[CONTENT])
    assert report.resets == 1, report.summary()


@pytest.mark.parametrize("transport", ["pty", "socket"])
def test_an_answer_whose_last_frame_was_lost_costs_one_retry(honest, tmp_path, transport):
    """Finding 2: the next clean answer used to fail too (`frames lost: expected seq N, got
    N+1`), so three such faults exhausted max_attempts 5."""
    params, clean = honest
    report, plan = acquire_from(HostileBoard(misbehaviour="last_lost"), tmp_path, params,
                                transport)
    assert report.retries == 1, report.summary()
    frame = ingest_log(tmp_path / "acquisition.log", plan).frame
    pd.testing.assert_frame_equal(frame[CONTENT], clean[CONTENT])


@pytest.mark.parametrize("transport", ["pty", "socket"])
def test_a_condition_no_answer_of_which_is_whole_is_assembled_from_their_valid_frames(
        honest, tmp_path, transport):
    """Issue 40's soak at max_attempts 5: every answer to one condition loses frames,
    different ones each time (even sample indices, then odd, ...). Old code stored only a
    whole answer and gave up after 5 (`failed 5 times`); now each answer's valid frames
    keep their places, the condition is asked again for its missing places, and the
    stored rows are the clean run's."""
    params, clean = honest
    report, plan = acquire_from(HostileBoard(misbehaviour="damage_each", at=50), tmp_path,
                                params, transport)
    # The first answer loses places 0, 2, 4; the top-up asks for those alone (SIM PICK,
    # issue 56) and loses none of them (before, it asked for 0..4 and lost 1 and 3: 5).
    assert report.retries == 1 and report.frames_rejected == 3, report.summary()
    text = (tmp_path / "acquisition.log").read_text()
    assembled = [line for line in text.splitlines()
                 if line.startswith("B\t") and "assembled_from" in line]
    assert len(assembled) == 1 and '"assembled_from": [50, 51]' in assembled[0], assembled
    frame = ingest_log(tmp_path / "acquisition.log", plan).frame
    pd.testing.assert_frame_equal(frame[CONTENT], clean[CONTENT])


def test_requests_cut_short_by_restarts_are_not_attempts_at_the_condition(honest, tmp_path):
    """Issue 40's soak at max_attempts 5 (the runner's default here): six requests in a row
    cut short by a restart half-way, then answered. Old code counted each as an attempt
    and gave up (`failed 5 times`); now they count against acquire.max_interruptions,
    and the frames before each restart keep their places."""
    params, clean = honest
    report, plan = acquire_from(HostileBoard(misbehaviour="restart_mid", at=50, times=6),
                                tmp_path, params)
    assert (report.acquired, report.resets, report.reconnects) == (CONDITIONS, 6, 0), \
        report.summary()
    frame = ingest_log(tmp_path / "acquisition.log", plan).frame
    pd.testing.assert_frame_equal(frame[CONTENT], clean[CONTENT])


@pytest.mark.parametrize("transport", ["pty", "socket"])
def test_a_restart_whose_hello_is_lost_is_a_restart_and_costs_nothing(honest, tmp_path,
                                                                       transport):
    """A reset tears the line being sent, and the #HELLO after it is glued to the torn
    line: the host sees junk, then silence; its probe's #OK looks like that of an answer
    whose #OK was lost. The next answer's seq, started again, tells: the board is told its
    stretch and weights again (before: a violation counted as an answer, and the board,
    which had forgotten them, was asked for the missing places as it was)."""
    params, clean = honest
    report, plan = acquire_from(HostileBoard(misbehaviour="restart_unheard", at=50),
                                tmp_path, params, transport)
    assert (report.acquired, report.resets, report.reconnects) == (CONDITIONS, 1, 0), \
        report.summary()
    frame = ingest_log(tmp_path / "acquisition.log", plan).frame
    pd.testing.assert_frame_equal(frame[CONTENT], clean[CONTENT])


def test_a_board_that_restarts_on_every_request_ends_after_max_interruptions(honest,
                                                                            tmp_path):
    """A board that restarts in every answer from the 50th request on: one line naming the
    condition, the count and the knob, exit 1, the 49 conditions before it kept. Old code
    counted the restarts as attempts (`failed 5 times`)."""
    params, _ = honest
    assert params["acquire"]["max_interruptions"] == 20
    code, stderr, _, _ = run_cli_against(
        HostileBoard(misbehaviour="restart_mid", at=50, times=10**6), tmp_path, params)
    lines = [line for line in stderr.splitlines() if line.startswith("eskin: error")]
    assert code == 1 and len(lines) == 1 and "Traceback" not in stderr, stderr
    fiftieth = plan_from_params("single_force", validate_params(params, Params).scenes[
        "single_force"]).conditions[49].describe()
    assert (f"single_force: {fiftieth} was cut short 20 times "
            "(acquire.max_interruptions)") in lines[0], lines[0]
    assert "(0 answer(s), 4 of its 5 frames valid)" in lines[0] \
        and "raise acquire.max_interruptions" in lines[0], lines[0]
    contents = read_log(tmp_path / "data" / "raw" / "single_force" / "acquisition.log")
    assert len(contents.completed) == 49, "what was recorded before is kept"


def test_a_frame_whose_board_time_fell_across_answers_is_never_stored(honest, tmp_path):
    """Finding 3: t_ms was checked within an answer only, so a first frame whose time fell
    from the last answer's (digits lost, CRC-8 matched by chance) was stored."""
    params, clean = honest
    board = HostileBoard(misbehaviour="time_back", at=50)
    report, plan = acquire_from(board, tmp_path, params)
    assert len(board.time_back) == 1 and report.retries == 1, report.summary()
    contents = read_log(tmp_path / "acquisition.log")
    stored = [f for a in contents.completed.values() for f in a.frames]
    assert board.time_back[0] not in {f.seq for f in stored}
    assert all(f.t_ms > 0 for f in stored), "the board's clock starts at 0, then STRETCH"
    frame = ingest_log(tmp_path / "acquisition.log", plan).frame
    pd.testing.assert_frame_equal(frame[CONTENT], clean[CONTENT])


@pytest.mark.parametrize("transport", ["socket", "pty"])
def test_a_1_mib_junk_line_costs_no_retry_and_no_reconnect(honest, tmp_path, transport):
    """Finding 4: a socket:// port was read a byte a call (94 kB/s), so a 1 MiB line
    outlasted the request's deadline and cost a reconnect; the answer after it is whole."""
    params, clean = honest
    report, plan = acquire_from(HostileBoard(misbehaviour="long_line", at=50), tmp_path,
                                params, transport)
    assert (report.retries, report.reconnects) == (0, 0), report.summary()
    assert report.frames_rejected >= 1
    frame = ingest_log(tmp_path / "acquisition.log", plan).frame
    pd.testing.assert_frame_equal(frame[CONTENT], clean[CONTENT])


@pytest.mark.heavy
def test_a_board_whose_lines_end_in_cr_only_is_given_up_on_with_the_hint(honest, tmp_path):
    """Finding 6: it ended as "lost the board" with no hint of why."""
    params, _ = honest
    code, stderr, seconds, _ = run_cli_against(HostileBoard(misbehaviour="cr_only", at=30),
                                               tmp_path, params)
    lines = [line for line in stderr.splitlines() if line.startswith("eskin: error")]
    assert code == 1 and len(lines) == 1 and "Traceback" not in stderr, stderr
    assert "lost the board" in lines[0] and "lines end in CR only" in lines[0], lines[0]
    assert seconds < 2 * TIMEOUT_S + RECONNECT_S + 8, seconds


# ---------------------------------------------------------------- findings 4-6

@pytest.mark.heavy
def test_a_kill_at_the_first_prompt_leaves_a_log_the_next_run_continues(tmp_path,
                                                                       repo_params):
    params = hostile_params(repo_params)
    with Served(HostileBoard()) as served:
        params["acquire"]["indenters"] = "person"
        params["scenes"]["single_force"].update(source="serial", port=served.port)
        write_params(tmp_path, params)
        child = subprocess.Popen([sys.executable, "-m", "eskin", "acquire", "single_force",
                                  "--no-progress"], cwd=tmp_path, stdin=subprocess.PIPE,
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        seen = b""
        deadline = time.monotonic() + 60
        while b"press Enter" not in seen and time.monotonic() < deadline:
            seen += os.read(child.stdout.fileno(), 1024)
        assert b"press Enter" in seen
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=10)
        log = tmp_path / "data" / "raw" / "single_force" / "acquisition.log"
        assert not log.exists() or log.read_text().startswith(MAGIC)
        params["acquire"]["indenters"] = "board"
        write_params(tmp_path, params)
        again = eskin(["acquire", "single_force", "--no-progress"], tmp_path)
    assert again.returncode == 0, again.stderr
    assert log.read_text().startswith(MAGIC + "\n")
    assert eskin(["ingest", "single_force"], tmp_path).returncode == 0


def skin_params(repo_params, rows, columns):
    """Small single-force params on a ``rows`` × ``columns`` skin: one stretch, 3 samples."""
    params = hostile_params(repo_params)
    params["scenes"]["single_force"].update(stretches=[1.0], forces=[0.0, 3.2536], samples=3,
                                            skin={"rows": rows, "columns": columns})
    return params


def test_a_board_of_8_by_8_terminals_gives_the_8_by_8_dataset(tmp_path, repo_params):
    """The independent board with 16 terminals, a scene on an 8 × 8 skin: every condition
    stored, 16 channels, the pressed row and column the raised ones."""
    params = skin_params(repo_params, 8, 8)
    report, plan = acquire_from(HostileBoard(rows=8, columns=8), tmp_path, params)
    assert report.conditions == 2 * 65 and report.frames_rejected == 0
    frame = ingest_log(tmp_path / "acquisition.log", plan).frame
    channels = [f"cx{i}" for i in range(1, 9)] + [f"cy{i}" for i in range(1, 9)]
    assert [c for c in frame.columns if c[:2] in ("cx", "cy")] == channels
    pressed = frame[(frame["force"] > 0) & (frame["x"] == 3) & (frame["y"] == 8)]
    assert len(pressed) == 3
    raised = pressed[channels].to_numpy() - frame.loc[frame["x"] == 0, channels].mean().to_numpy()
    assert set(np.flatnonzero(raised.min(axis=0) > 60)) == {2, 8 + 7}  # cx3 and cy8


@pytest.mark.parametrize(("rows", "columns", "board"), [(10, 10, (8, 8)), (16, 12, (10, 10))])
def test_a_board_of_another_size_is_refused_in_one_line_and_nothing_is_lost(
        tmp_path, repo_params, rows, columns, board):
    """`eskin acquire` on a scene whose skin is not the board's: exit 1, one line with
    both counts and the key to set, and the raw log as it was, byte for byte."""
    params = skin_params(repo_params, rows, columns)
    if (rows, columns) == (10, 10):
        del params["scenes"]["single_force"]["skin"]  # the paper's skin, by default
    log = tmp_path / "data" / "raw" / "single_force" / "acquisition.log"
    log.parent.mkdir(parents=True)
    log.write_bytes(b"#eskin-raw 1\n")
    code, stderr, _, _ = run_cli_against(HostileBoard(rows=board[0], columns=board[1]),
                                         tmp_path, params)
    terminals = sum(board)
    assert code == 1 and "Traceback" not in stderr, stderr
    assert stderr.count("\n") == 1, stderr
    assert (f"has {terminals} terminals (terminals={terminals} in its #HELLO), but the "
            f"scene's skin is the {rows} × {columns} row/column skin ({rows + columns} "
            "terminals): set scenes.single_force.skin to the board's rows and columns "
            f"({{rows: R, columns: C}} with R + C = {terminals})") in stderr, stderr
    assert log.read_bytes() == b"#eskin-raw 1\n"


def test_an_empty_or_headerless_log_from_an_earlier_version_is_continued(honest, tmp_path):
    params, clean = honest
    plan = plan_from_params("single_force", validate_params(params, Params).scenes["single_force"])
    log = tmp_path / "acquisition.log"
    log.write_bytes(b"")
    acquire_from(HostileBoard(), tmp_path, params)
    assert log.read_text().startswith(MAGIC + "\n")
    log.write_text(log.read_text().removeprefix(MAGIC + "\n"))  # as eskin 0.1.0 left it
    assert read_log(log).headerless
    grown = copy.deepcopy(params)
    grown["scenes"]["single_force"]["stretches"].append(1.15842)
    report, grown_plan = acquire_from(HostileBoard(), tmp_path, grown)
    assert (report.acquired, report.reused) == (CONDITIONS, CONDITIONS)
    assert log.read_text().startswith(MAGIC + "\n") and not read_log(log).headerless
    frame = ingest_log(log, plan).frame
    pd.testing.assert_frame_equal(frame[CONTENT], clean[CONTENT])


def test_more_samples_per_condition_acquires_them_and_fewer_reuses(honest, tmp_path):
    params, clean = honest
    acquire_from(HostileBoard(), tmp_path, params)
    more = copy.deepcopy(params)
    more["scenes"]["single_force"]["samples"] = 6
    report, plan = acquire_from(HostileBoard(), tmp_path, more)
    assert (report.acquired, report.reused) == (CONDITIONS, 0), report.summary()
    frame = ingest_log(tmp_path / "acquisition.log", plan).frame
    assert len(frame) == CONDITIONS * 6
    again, _ = acquire_from(HostileBoard(), tmp_path, more)
    assert (again.acquired, again.reused) == (0, CONDITIONS)
    fewer, plan = acquire_from(HostileBoard(), tmp_path, params)
    assert (fewer.acquired, fewer.reused) == (0, CONDITIONS)
    assert len(ingest_log(tmp_path / "acquisition.log", plan).frame) == CONDITIONS * 5


@pytest.mark.parametrize("encoding", ["utf-8", "ascii"])
def test_operator_input_closed_is_one_line_and_ascii_terminals_work(tmp_path, repo_params,
                                                                    encoding):
    params = hostile_params(repo_params)
    with Served(HostileBoard()) as served:
        params["acquire"]["indenters"] = "person"
        params["scenes"]["single_force"].update(source="serial", port=served.port)
        write_params(tmp_path, params)
        result = eskin(["acquire", "single_force", "--no-progress"], tmp_path,
                       stdin=subprocess.DEVNULL,
                       env={**os.environ, "PYTHONIOENCODING": encoding})
    assert result.returncode == 1 and "Traceback" not in result.stderr, result.stderr
    assert result.stderr.count("\n") == 1 and "operator input closed" in result.stderr
    if encoding == "ascii":
        assert "stretch=1" in result.stdout  # the prompt, readable without λ


# ---------------------------------------------------------------- finding 7: params.yaml

MISTAKES = {
    "folds: \"ten\"": (("cv", "folds"), "ten", "cv.folds = 'ten': Input should be a valid integer"),
    "folds: 2.5": (("cv", "folds"), 2.5, "cv.folds = 2.5: Input should be a valid integer"),
    "samples: 2.7": (("scenes", "single_force", "samples"), 2.7, "samples = 2.7"),
    "forces: 1.0": (("scenes", "single_force", "forces"), 1.0, "valid list"),
    "forces: []": (("scenes", "single_force", "forces"), [], "at least 1 item"),
    "forces: [nan]": (("scenes", "single_force", "forces"), [float("nan")], "finite number"),
    "reconnect_s: -5": (("acquire", "reconnect_s"), -5, "greater than or equal to 0"),
    "max_attempts: 0": (("acquire", "max_attempts"), 0, "greater than or equal to 1"),
    "max_interruptions: 0": (("acquire", "max_interruptions"), 0,
                             "greater than or equal to 1"),
    "sim.noise_pf missing": (("sim", "noise_pf"), None, "sim.noise_pf is missing (required)"),
    "unknown key": (("acquire", "prot"), 1, "acquire.prot is not a known key of acquire"),
    "hyperparameters not a mapping": (("train", "force", "paper"), 3,
                                      "train.force.paper = 3: Input should be "
                                      "a valid dictionary"),
    "a task missing": (("train", "detect"), None, "train.detect is missing (required)"),
    "source typo": (("scenes", "two_force", "source"), "serail", "scenes.two_force.source = "
                    "'serail': Input should be 'simulated', 'emulated', 'serial' or "
                    "'import'"),
    "import with no file": (("scenes", "two_force", "source"), "import",
                            "scenes.two_force: an import scene's labels come from its files, "
                            "not a plan: remove stretches, forces, samples, nodes_x, nodes_y, "
                            "contact_counts; "
                            "set import.path to the files"),
    "serial with no port": (("scenes", "two_force", "source"), "serial",
                            "scenes.two_force: source is 'serial' but port is unset"),
}


@pytest.mark.parametrize("mistake", sorted(MISTAKES))
def test_a_params_mistake_is_one_line_naming_the_key(tmp_path, repo_params, mistake):
    path, value, expected = MISTAKES[mistake]
    params = copy.deepcopy(repo_params)
    node = params
    for part in path[:-1]:
        node = node[part]
    if value is None:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    write_params(tmp_path, params)
    result = eskin(["ingest", "single_force"], tmp_path)
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert result.stderr.count("\n") == 1 and expected in result.stderr, result.stderr


def test_invalid_yaml_and_a_directory_import_path_are_one_line(tmp_path, repo_params):
    (tmp_path / "params.yaml").write_text("cv:\n  folds: [1\n")
    result = eskin(["ingest", "single_force"], tmp_path)
    assert result.returncode == 1 and result.stderr.startswith(
        "eskin: error: params.yaml:3:1: not valid YAML"), result.stderr
    params = copy.deepcopy(repo_params)
    params["scenes"]["single_force"] = {"kind": "single_force", "source": "import",
                                        "import": {"path": str(tmp_path)}}
    write_params(tmp_path, params)
    result = eskin(["acquire", "single_force"], tmp_path)
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert "the folder has no CSV or Parquet file" in result.stderr and \
        "import.path" in result.stderr, result.stderr


# ---------------------------------------------------------------- issue 56

def test_protocol_an_ok_that_is_not_the_answers_is_fenced_so_the_host_is_never_behind():
    """Item 1: a duplicated #OK SAMPLE n closed the next request with 0 frames, and with no
    fence its real #OK closed the request after, one reply behind for good."""
    host = greeted()
    host.send_sample(3)
    host.receive(frames(0, 3) + b"#OK SAMPLE 3\n")
    host.send_sample(3)
    events = host.receive(b"#OK SAMPLE 3\n")  # the duplicate, alone in its read
    assert events == [SampleIncomplete(3, 0, 3)] and host.needs_fence
    host.send_fence()  # its real answer, then the fence's #OK
    events = host.receive(frames(3, 3) + b"#OK SAMPLE 3\n#OK STREAM OFF\n")
    assert [type(e) for e in events] == [Stray] * 3 + [Answered]
    host.send_sample(3)  # placed by seq: the first answer's seqs are owed
    events = host.receive(frames(6, 3) + b"#OK SAMPLE 3\n")
    assert [(type(e), getattr(e, "index", None)) for e in events] == [
        (SampleFrame, 0), (SampleFrame, 1), (SampleFrame, 2), (SampleComplete, None)]
    host.receive(b"#OK SAMPLE 3\n")  # an #OK with no request open: fenced too
    assert host.needs_fence


@pytest.mark.parametrize("transport", ["pty", "socket"])
@pytest.mark.parametrize("misbehaviour", ["dup_ok", "spoof_ok"])
def test_a_duplicated_or_spoofed_ok_costs_one_retry(honest, tmp_path, misbehaviour,
                                                     transport):
    """Item 1, with SIM commands between requests: old code spent two answers on it (the
    duplicate closed one request, its real #OK broke the next command)."""
    params, clean = honest
    report, plan = acquire_from(HostileBoard(misbehaviour=misbehaviour, at=50), tmp_path,
                                params, transport)
    assert (report.retries, report.reconnects) == (1, 0), report.summary()
    frame = ingest_log(tmp_path / "acquisition.log", plan).frame
    pd.testing.assert_frame_equal(frame[CONTENT], clean[CONTENT])


@pytest.mark.parametrize("transport", ["pty", "socket"])
@pytest.mark.parametrize("misbehaviour", ["dup_ok", "spoof_ok"])
def test_a_stray_ok_on_a_bench_that_sends_only_samples_costs_one_retry(
        honest, tmp_path, misbehaviour, transport):
    """Item 1 on a real rig, where a retry is SAMPLE again and nothing else: the answer's
    own #OK closed the retry too (old code: 2 retries)."""
    params, _ = honest
    report, _ = acquire_from(HostileBoard(misbehaviour=misbehaviour, at=50), tmp_path,
                             params, transport, placer=OperatorPlacer(ask=lambda _: None))
    assert (report.acquired, report.retries, report.reconnects) == (CONDITIONS, 1, 0), \
        report.summary()


@pytest.mark.parametrize("transport", ["pty", "socket"])
def test_a_lost_ok_costs_a_short_gap_not_the_timeout_and_a_reconnect(honest, tmp_path,
                                                                      transport):
    """Item 4: at the default timeout_s (5 s) a lost #OK SAMPLE cost the whole timeout and a
    reconnect. Now a silence of 0.25 s after a frame sends the probe (STREAM OFF, the
    request left open); its #OK says the answer is over: all its frames came, so it is
    whole, with no retry."""
    params, clean = honest
    started = time.monotonic()
    report, plan = acquire_from(HostileBoard(misbehaviour="lost_ok", at=50), tmp_path,
                                params, transport, timeout_s=5.0)
    assert (report.retries, report.reconnects) == (0, 0), report.summary()
    assert time.monotonic() - started < 4.0, report.summary()
    frame = ingest_log(tmp_path / "acquisition.log", plan).frame
    pd.testing.assert_frame_equal(frame[CONTENT], clean[CONTENT])


def test_protocol_a_probe_ends_an_answer_whose_ok_was_lost_and_is_absorbed_after_one():
    host = greeted()
    host.send_sample(3)
    host.receive(frames(0, 3))
    assert host.answer_begun
    host.send_probe()
    events = host.receive(b"#OK STREAM OFF\n")
    assert events == [SampleComplete(2, 3)] and not host.needs_fence
    host.send_sample(3)  # the probe came too soon: the answer's own #OK, then the probe's
    host.receive(frames(3, 2))
    host.send_probe()
    events = host.receive(frames(5, 1) + b"#OK SAMPLE 3\n#OK STREAM OFF\n")
    assert isinstance(events[-1], SampleComplete) and not host.needs_fence
    host.send_command("SIM CLEAR")
    assert [type(e) for e in host.receive(b"#OK SIM CLEAR\n")] == [Answered]


@pytest.mark.parametrize("first_seq", [0, 1], ids=["its-first-frame", "its-first-lost"])
def test_protocol_a_probe_answered_by_a_board_that_restarted_unheard_places_nothing(
        first_seq):
    """The emulated firmware, reset mid-answer: its last line torn, its #HELLO glued to it
    and lost. The probe's #OK then looks like a lost #OK's, and the next answer's frames
    come from a count started again: none is placed after the old answer's (seq 1 at
    place 0 of a top-up would be a frame one place off). A count that went back is a
    restart (the runner tells the board its stretch and weights again); seqs the old
    answer owned are stray."""
    host = greeted()
    host.send_sample(4)
    torn = frame_line(1, 12, [500] * 20)[:30]
    events = host.receive(frames(0, 1) + torn
                          + b"#HELLO eskin fw terminals=20 adc_bits=10 id=b1\n")
    assert [type(e) for e in events] == [SampleFrame, Junk]
    host.send_probe()
    assert host.receive(b"#OK STREAM OFF\n") == [SampleIncomplete(2, 1, 4)]
    host.send_sample(3)
    events = host.receive(frames(first_seq, 3 - first_seq) + b"#OK SAMPLE 3\n")
    assert not any(isinstance(e, SampleFrame) for e in events), events
    if first_seq == 0:
        assert isinstance(events[0], Violation) and events[0].restart, events
        assert host.needs_fence
    else:
        assert [type(e) for e in events] == [Stray, Stray, SampleIncomplete], events


def test_an_err_stops_the_run_saying_what_the_board_said_and_that_rerunning_resumes(
        honest, tmp_path):
    params, _ = honest
    code, stderr, _, _ = run_cli_against(HostileBoard(misbehaviour="refuse", at=50),
                                         tmp_path, params)
    lines = [line for line in stderr.splitlines() if line.startswith("eskin: error")]
    assert code == 1 and len(lines) == 1 and "Traceback" not in stderr, stderr
    assert "it said '#ERR SAMPLE busy'" in lines[0], lines[0]
    # The 49th condition's last frame had no frame after it to judge its board time.
    assert "48 condition(s) complete so far are kept" in lines[0], lines[0]
    assert "rerunning resumes after the last of them" in lines[0], lines[0]
    log = tmp_path / "data" / "raw" / "single_force" / "acquisition.log"
    assert len(read_log(log).completed) == 48


def test_protocol_judges_each_frame_by_both_neighbours():
    """Item 2: a frame whose time fell was followed, so a second fallen frame passed; a
    frame whose time jumped forward was kept and the frame after it refused."""
    host = greeted()
    host.send_sample(5)
    jumped = frame_line(2, 100_000, [500] * 20)
    events = host.receive(frames(0, 2) + jumped + frames(3, 2) + b"#OK SAMPLE 5\n")
    assert [type(e) for e in events] == [SampleFrame] * 3 + [TimeJumped, SampleFrame,
                                                             SampleFrame, SampleIncomplete]
    assert events[3].frame.seq == 2 and events[3].index == 2 and events[-1].frames == 4
    host.send_sample(4)  # seq 5 and 6 fell, to 0 and then above it: both are refused
    events = host.receive(frame_line(5, 0, [500] * 20) + frame_line(6, 7, [500] * 20)
                          + frames(7, 2) + b"#OK SAMPLE 4\n")
    assert [type(e) for e in events] == [Junk, Junk, SampleFrame, SampleFrame,
                                         SampleIncomplete]
    host.send_sample(1)  # a last frame jumps: watched, judged by the next answer's first
    host.receive(frame_line(9, 100_000, [500] * 20) + b"#OK SAMPLE 1\n")
    host.watch(host.last_accepted)
    assert host.watch_open and host.watched_verdict is None
    host.send_sample(1)
    events = host.receive(frames(10, 1) + b"#OK SAMPLE 1\n")
    assert isinstance(events[0], TimeJumped) and events[0].frame.seq == 9
    assert host.watched_verdict is False
    host.watch(host.last_accepted)  # seq 10; seq 11 vouches for it
    host.send_sample(1)
    host.receive(frames(11, 1) + b"#OK SAMPLE 1\n")
    assert host.watched_verdict is True


@pytest.mark.parametrize("transport", ["pty", "socket"])
def test_a_frame_whose_time_jumped_forward_is_never_stored_and_costs_one_retry(
        honest, tmp_path, transport):
    """Item 2: eskin cf46b9c stored the jumped frame (an answer's last) and refused the next
    good answer (its first frame's time fell from the jumped one)."""
    params, clean = honest
    board = HostileBoard(misbehaviour="time_jump", at=50)
    report, plan = acquire_from(board, tmp_path, params, transport)
    assert len(board.time_jumped) == 1 and report.retries == 1, report.summary()
    contents = read_log(tmp_path / "acquisition.log")
    stored = [f for a in contents.completed.values() for f in a.frames]
    assert board.time_jumped[0] not in {f.seq for f in stored}
    frame = ingest_log(tmp_path / "acquisition.log", plan).frame
    pd.testing.assert_frame_equal(frame[CONTENT], clean[CONTENT])
    _assert_time_rises_as_sent(contents)


@pytest.mark.parametrize("transport", ["pty", "socket"])
def test_a_second_fallen_frame_is_caught_as_surely_as_the_first(honest, tmp_path,
                                                                  transport):
    """Item 2: the host followed a fallen time, so the next answer's first frame, fallen
    too but above the first, was stored (eskin cf46b9c: 3 rows with backward time)."""
    params, clean = honest
    board = HostileBoard(misbehaviour="time_back_twice", at=50)
    report, plan = acquire_from(board, tmp_path, params, transport)
    assert len(board.time_back) == 2 and report.retries == 2, report.summary()
    contents = read_log(tmp_path / "acquisition.log")
    stored = {f.seq for a in contents.completed.values() for f in a.frames}
    assert not stored & set(board.time_back)
    frame = ingest_log(tmp_path / "acquisition.log", plan).frame
    pd.testing.assert_frame_equal(frame[CONTENT], clean[CONTENT])
    _assert_time_rises_as_sent(contents)


def _assert_time_rises_as_sent(contents):
    """Over each stored condition's frames in the order the board sent them (by seq: these
    runs have no restart), board time never falls."""
    for attempt in contents.completed.values():
        times = [f.t_ms for f in sorted(attempt.frames, key=lambda f: f.seq)]
        assert times == sorted(times), (attempt.condition["key"], times)


@pytest.mark.parametrize("transport", ["pty", "socket"])
def test_a_frame_glued_to_an_overlong_line_is_dropped_with_it(honest, tmp_path, transport):
    """Item 5: the parser emptied its buffer at 246 bytes, so when a read ended where a
    64 KiB burst did, the frame glued to its end parsed and was stored (eskin cf46b9c:
    35 rows on a socket). By the line rule that frame was lost: its place is asked again."""
    params, clean = honest
    board = HostileBoard(misbehaviour="glued_long_line", at=50)
    report, plan = acquire_from(board, tmp_path, params, transport)
    assert (report.retries, report.reconnects) == (1, 0), report.summary()
    contents = read_log(tmp_path / "acquisition.log")
    stored = {f.seq for a in contents.completed.values() for f in a.frames}
    assert board.glued[0] not in stored
    frame = ingest_log(tmp_path / "acquisition.log", plan).frame
    pd.testing.assert_frame_equal(frame[CONTENT], clean[CONTENT])


@pytest.mark.parametrize("transport", ["pty", "socket"])
def test_a_top_up_asks_only_for_the_missing_places(honest, tmp_path, transport):
    """Item 3: the top-up asked for every place from the first missing one on and kept only
    the empty ones (eskin cf46b9c: 3,504-3,552 frames asked for 2,020 stored at 10 %
    damage, on two stretches). With SIM PICK it asks for the missing places alone: at most
    1.2 frames asked per frame stored, the data the honest run's."""
    params, clean = honest
    board = HostileBoard(damage_rate=0.1, seed=7)
    report, plan = acquire_from(board, tmp_path, params, transport)
    assert report.frames_stored == CONDITIONS * 5, report.summary()
    assert report.frames_rejected > 0.075 * report.frames_stored, report.summary()
    assert board.frames_asked / report.frames_stored <= 1.2, (board.frames_asked,
                                                              report.summary())
    frame = ingest_log(tmp_path / "acquisition.log", plan).frame
    pd.testing.assert_frame_equal(frame[CONTENT], clean[CONTENT])


def test_a_board_older_than_sim_pick_is_topped_up_as_before(honest, tmp_path):
    """Old boards keep working: SIM PICK refused (#ERR), the placer asks from the first
    missing place on (SIM REPLAY), as eskin did before, for the rest of the run."""
    params, clean = honest
    board = HostileBoard(damage_rate=0.1, seed=7, picks=False)
    report, plan = acquire_from(board, tmp_path, params)
    assert report.frames_stored == CONDITIONS * 5, report.summary()
    assert board.frames_asked / report.frames_stored > 1.2, board.frames_asked
    frame = ingest_log(tmp_path / "acquisition.log", plan).frame
    pd.testing.assert_frame_equal(frame[CONTENT], clean[CONTENT])


def test_protocol_after_a_stray_ok_or_an_unplaced_answer_the_next_is_still_placed():
    """The acceptance soak on a pty: a duplicated #OK landed on a SAMPLE (a violation), and
    the fence forgot the next seq; each later answer, its first line damaged, was unplaced
    and kept nothing (only a whole one places), so the condition failed 5 times."""
    host = greeted()
    host.send_sample(2)
    host.receive(frames(0, 2) + b"#OK SAMPLE 2\n")
    host.send_sample(2)
    events = host.receive(b"#OK SIM PICK 20 2\n")  # a duplicate of another command's #OK
    assert isinstance(events[0], Violation) and host.needs_fence
    host.send_fence()
    host.receive(frames(2, 2) + b"#OK SAMPLE 2\n#OK STREAM OFF\n")  # owed, then the fence
    host.send_sample(2)  # placed by seq: its damaged first line leaves place 0 empty
    events = host.receive(damaged(frame_line(4, 48, [500] * 20)) + frames(5, 1)
                          + b"#OK SAMPLE 2\n")
    assert [(e.index, e.placed) for e in events if isinstance(e, SampleFrame)] == [(1, True)]
    host.reset_link()  # a connect: no seq known
    host.send_fence()
    host.receive(b"#OK STREAM OFF\n")
    host.send_sample(2)  # unplaced (a damaged line first), but its last line was a frame
    host.receive(damaged(frame_line(6, 72, [500] * 20)) + frames(7, 1) + b"#OK SAMPLE 2\n")
    host.send_fence()
    host.receive(b"#OK STREAM OFF\n")
    host.send_sample(2)  # ... so the next begins after it, and is placed
    events = host.receive(damaged(frame_line(8, 96, [500] * 20)) + frames(9, 1)
                          + b"#OK SAMPLE 2\n")
    assert [(e.index, e.placed) for e in events if isinstance(e, SampleFrame)] == [(1, True)]


@pytest.mark.parametrize("transport", ["pty", "socket"])
def test_a_place_the_line_keeps_losing_is_asked_twice_per_request(honest, tmp_path,
                                                                 transport):
    """The acceptance soak at 10 % damage: a place lost 4 times running ended the condition
    at max_attempts 5 (about once in 10,000 missing places; the soak's 24,240 samples lose
    about 2,400). A place asked for twice in vain is asked twice in one request."""
    params, clean = honest
    board = HostileBoard(misbehaviour="lose_place", at=50)
    report, plan = acquire_from(board, tmp_path, params, transport)
    assert board.lost_sends == 5 and report.retries == 3, report.summary()
    frame = ingest_log(tmp_path / "acquisition.log", plan).frame
    pd.testing.assert_frame_equal(frame[CONTENT], clean[CONTENT])
