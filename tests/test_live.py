"""Live: a trained stack on the simulated board's stream, against the same stack in batch.

The board streams over a real pty (its own process); presses are scripted through its
``SIM`` commands while it streams. The stack's live estimates, frame by frame as they
arrive, must equal its batch predictions for the same frames.
"""

from __future__ import annotations

import contextlib
import json
import queue
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request

import numpy as np
import pandas as pd
import pytest

from eskin.acquisition.session import simulated_board
from eskin.config.live import Live
from eskin.deploy.export import write_stack
from eskin.deploy.live import (
    LineBroadcast,
    LiveRecorder,
    Tare,
    json_line,
    live_estimates,
    stream_events,
)
from eskin.deploy.stack import ExportedStack, SkinStack, StackError
from eskin.deploy.view import LiveView, Pressing, PressRefused
from eskin.device.host import HostProtocol, StreamFrame, StreamGap
from eskin.device.link import SerialLink
from eskin.device.physics import skin_params
from eskin.device.protocol import encode_frame
from eskin.skin import PAPER_SKIN, ChannelArray, Skin
from tests.conftest import (
    ROOT,
    acquire_step,
    headless_chromium,
    ingest_step,
    needs_chromium,
    prepared_scene,
    small_scenes,
    small_stack,
    typed,
)
from tests.hostile_board import HostileBoard, Served

TARE = 50
# Live as the batch stack: the tare's offset kept, the stack's own contact verdict. The
# baseline tracking and the hysteresis (issue 39) are tests/test_live_ghosts.py's.
AS_BATCH = Live.model_validate({"baseline": {"time_constant_s": 0, "gate_counts": 8},
                                "contact": {"enter_probability": 0.5,
                                            "leave_probability": 0.5,
                                            "min_duration_ms": 0}})


@pytest.fixture(scope="module")
def stack(tmp_path_factory, repo_params):
    """The repo's default models, trained on the small single-force scene."""
    params = small_scenes(repo_params)
    return params, small_stack(params, tmp_path_factory.mktemp("live"))


# (command sent once this many estimates are out, what it does). Estimates trail the
# board by a batch or so (the frames that arrived while the last was predicted: 10 to 15
# here), so each phase is judged on its last 20 estimates only.
SCRIPT = [
    (60, "SIM PRESS 5 5 3.2536"),  # the small scene's one weight
    (120, "SIM CLEAR"),
    (170, "SIM PRESS 2 8 3.2536"),
    (230, "SIM CLEAR"),
    (260, "STRETCH 8"),
]


def run_live(params, stack, *, corrupt_fraction=0.0, estimates_wanted=320, record_to=None,
             faults=None, script=SCRIPT):
    """Stream, run the script, and keep every stream event and every live record (and,
    ``record_to`` a raw directory, record the stream there as ``--record`` does)."""
    settings = typed(params).acquire
    events, records = [], []
    with contextlib.ExitStack() as resources:
        board = resources.enter_context(simulated_board(
            skin_params(typed(params).sim), rest_length_mm=float(settings.rest_length_mm),
            corrupt_fraction=corrupt_fraction, frame_period_ms=8, faults=faults))
        link = resources.enter_context(SerialLink(board.port, timeout_s=5.0))
        hello = link.connect()
        stack.check_board(hello.device_id)

        def kept(batches):
            for batch in batches:
                events.extend(batch)
                yield batch

        stream = resources.enter_context(contextlib.closing(stream_events(link)))
        if record_to is not None:
            recorder = LiveRecorder.open(record_to, "single_force", hello,
                                         source="simulated", port="pty", stack="test",
                                         chunk=100)
            resources.callback(recorder.close)
            stream = recorder.tap(stream)
        script = list(script)
        estimates = 0
        for record in live_estimates(stack, kept(stream), tare_frames=TARE,
                                     settings=AS_BATCH):
            records.append(record)
            estimates += "seq" in record
            if script and estimates >= script[0][0]:
                link.command(script.pop(0)[1])  # while the board streams
            if estimates >= estimates_wanted:
                break
    return events, records


def live_against_batch(events, records, reference: SkinStack, estimates_wanted: int
                       ) -> pd.DataFrame:
    """The live estimates, checked against ``reference``'s batch predictions of the same
    frames (after the same tare)."""
    frames = [e.frame for e in events if isinstance(e, StreamFrame)]
    estimates = [r for r in records if "seq" in r]
    assert len(estimates) == estimates_wanted and records[0] == {"tare": records[0]["tare"]}
    tare = Tare.take(np.array([f.counts for f in frames[:TARE]]), reference.rest)
    by_seq = {f.seq: f for f in frames}
    live_frames = [by_seq[r["seq"]] for r in estimates]
    batch = reference.predict(tare.apply(np.array([f.counts for f in live_frames])))
    live = pd.DataFrame(estimates)
    assert list(live["seq"]) == sorted(live["seq"]) and live["seq"].is_unique
    assert list(live["t_ms"]) == [f.t_ms for f in live_frames]
    assert (live["contact"] == batch["contact"]).all()
    for name in ("x", "y"):
        assert np.array_equal(live[name].astype(float), batch[name], equal_nan=True)
    for name in ("stretch", "force", "contact_probability"):
        # JSON carries 6 decimals
        assert np.allclose(live[name].astype(float), batch[name], rtol=0, atol=5e-7)
    return live


@pytest.mark.heavy
def test_the_exported_stack_live_gives_the_scikit_learn_stacks_batch_estimates(stack,
                                                                                tmp_path):
    params, skin = stack
    exported = ExportedStack.from_file(write_stack(skin, tmp_path / "stack.onnx", sources={}))
    events, records = run_live(params, exported, estimates_wanted=260)
    live = live_against_batch(events, records, skin, 260)
    # The press was seen. Not on every frame: the simulator's drift is an unbounded random
    # walk and the stack never re-tares (issue 39), and on the data drawn since the
    # simulator's identity became behavioural the small scene's detector misses 1 or 2
    # pressed frames in 15 and calls 1 untouched frame in 20 touched.
    assert live.iloc[85:100]["contact"].mean() >= 0.8
    assert live.iloc[40:60]["contact"].mean() <= 0.1


@pytest.mark.heavy
def test_live_estimates_equal_the_batch_predictions_of_the_same_frames(stack):
    params, skin = stack
    events, records = run_live(params, skin)
    live = live_against_batch(events, records, skin, 320)
    # And the script was seen: the presses where they were made, the stretch after it.
    # Tolerances for the drift's ghosts and misses (issue 39): see the test above.
    untouched, pressed = live.iloc[40:60], live.iloc[85:100]
    assert untouched["contact"].mean() <= 0.1
    assert pressed["contact"].mean() >= 0.8 and (pressed["x"] == 5).mean() > 0.7
    assert (pressed["force"] - 3.2536).abs().median() < 0.5
    again = live.iloc[210:230]
    assert again["contact"].mean() >= 0.8 and (again["y"] == 8).mean() > 0.7
    assert untouched["stretch"].mean() < 1.02 < live.iloc[300:]["stretch"].mean()


@pytest.mark.heavy
def test_record_keeps_the_stream_in_the_raw_log_apart_from_the_training_data(stack, tmp_path):
    """`--record`: every streamed frame, damaged lines and gaps included, goes into the
    scene's raw log as a live session; ingest gives the same training data as before and
    the recorded frames beside it, and acquisition still finds nothing left to do."""
    from eskin.data.rawlog import read_log

    params, skin = stack
    processed = prepared_scene(params, "single_force", tmp_path)
    raw = tmp_path / "raw" / "single_force"
    before = pd.read_parquet(processed)
    events, records = run_live(params, skin, corrupt_fraction=0.03, estimates_wanted=250,
                               record_to=raw)
    streamed = [e.frame.seq for e in events if isinstance(e, StreamFrame)]
    log = read_log(raw / "acquisition.log")
    live = [s for s in log.sessions if s.get("mode") == "live"]
    assert [s["session"] for s in live] == ["live001"] and log.bad_lines == []
    attempts = sorted((a for a in log.completed.values() if a.session.get("mode") == "live"),
                      key=lambda a: a.number)
    assert all(len(a.frames) <= 100 for a in attempts)
    for attempt in attempts:  # each an unbroken run of the board's sequence
        assert np.all(np.diff([f.seq for f in attempt.frames]) == 1)
    assert any(len(a.frames) < 100 for a in attempts[:-1])  # a gap ended one early
    message = ingest_step(params, "single_force", raw, tmp_path / "processed").summary
    assert f"{len(streamed)} live-recorded frame(s) of 1 session(s)" in message
    after = pd.read_parquet(processed)
    pd.testing.assert_frame_equal(after, before)
    recorded = pd.read_parquet(tmp_path / "processed" / "single_force.live.parquet")
    assert list(recorded["seq"]) == streamed and set(recorded["session"]) == {"live001"}
    size = (raw / "acquisition.log").stat().st_size
    acquire_step(params, "single_force", raw, progress=False)  # nothing left to acquire
    assert (raw / "acquisition.log").stat().st_size == size


@pytest.mark.heavy
def test_the_stream_goes_on_across_board_restarts_and_a_vanishing_port(stack, tmp_path):
    """As acquisition does: a board that restarts streams again, a port that vanishes is
    reopened; the estimates go on, each from a frame that arrived."""
    from eskin.device.faults import LinkFaults

    params, skin = stack
    log = tmp_path / "faults.log"
    events, records = run_live(params, skin, estimates_wanted=500, script=[],
                               faults=LinkFaults(reset=0.004, vanish=0.004, vanish_s=0.3,
                                                 seed=3, log=str(log)),
                               record_to=tmp_path / "raw")
    kinds = [line.split("\t")[0] for line in log.read_text().splitlines()]
    assert kinds.count("reset") >= 1 and kinds.count("vanish") >= 1, kinds
    estimates = [r for r in records if "seq" in r]
    assert len(estimates) == 500
    arrived = [e.frame.seq for e in events if isinstance(e, StreamFrame)]
    assert [r["seq"] for r in estimates] == arrived[TARE:TARE + 500]
    assert np.any(np.diff(arrived) < 0)  # the board restarted
    # Recorded whole, in unbroken runs: a restart ends one.
    from eskin.data.rawlog import read_log

    attempts = sorted(read_log(tmp_path / "raw" / "acquisition.log").completed.values(),
                      key=lambda a: a.number)
    assert [f.seq for a in attempts for f in a.frames] == arrived
    assert all(np.all(np.diff([f.seq for f in a.frames]) == 1) for a in attempts)


def live_on_hostile(skin, board: HostileBoard, wanted: int, record_to=None, *,
                    timeout_s=5.0, reconnect_s=2.0, notes=None, wall_s=60.0):
    """``live_estimates`` on the independent board (tests/hostile_board.py) over a pty:
    the records, and the error that ended them, if one did. ``notes`` collects what live
    says on the way; after ``wall_s`` of records it stops, with no error (a hang)."""
    records, error = [], None
    say = (lambda message: None) if notes is None else notes.append
    started = time.monotonic()
    with Served(board) as served, SerialLink(served.port, timeout_s=timeout_s) as link:
        hello = link.connect()
        stream = contextlib.closing(stream_events(link, reconnect_s=reconnect_s, notify=say))
        with stream as events:
            recorder = None if record_to is None else LiveRecorder.open(
                record_to, "single_force", hello, source="serial", port=served.port,
                stack="test", chunk=100)
            try:
                tapped = events if recorder is None else recorder.tap(events)
                for record in live_estimates(skin, tapped, tare_frames=TARE,
                                             settings=AS_BATCH):
                    records.append(record)
                    if (sum("seq" in r for r in records) >= wanted
                            or time.monotonic() - started > wall_s):
                        break
            except Exception as err:  # noqa: BLE001 - the test looks at it
                error = err
            finally:
                if recorder is not None:
                    recorder.close()
    return records, error


@pytest.mark.heavy
def test_live_on_an_independent_board_predicts_exactly_the_frames_it_sent(stack):
    """A board that shares none of eskin's protocol code: every frame it streamed is
    parsed to its own counts and predicted once, in order, as the batch stack would."""
    _, skin = stack
    board = HostileBoard()
    records, error = live_on_hostile(skin, board, wanted=200)
    assert error is None
    estimates = [r for r in records if "seq" in r]
    sent = dict(board.sent)
    assert [r["seq"] for r in estimates] == [seq for seq, _ in board.sent[TARE:TARE + 200]]
    tare = Tare.take(np.array([counts for _, counts in board.sent[:TARE]], dtype=float),
                     skin.rest)
    batch = skin.predict(tare.apply(np.array([sent[r["seq"]] for r in estimates], float)))
    assert np.allclose(pd.DataFrame(estimates)["stretch"], batch["stretch"], atol=5e-7)
    assert (pd.DataFrame(estimates)["contact"] == batch["contact"]).all()


@pytest.mark.heavy
def test_another_board_mid_stream_ends_live_and_none_of_its_frames_is_kept(stack, tmp_path):
    """The wave's bug, live: another board's #HELLO mid-stream, then its frames from seq 0.
    eskin live stops with one line naming both ids; nothing of the other board is
    predicted or recorded."""
    from eskin.data.rawlog import read_log
    from eskin.device.link import DeviceChanged

    _, skin = stack
    board = HostileBoard(misbehaviour="stream_other_board", at=150)
    notes = []
    records, error = live_on_hostile(skin, board, wanted=400, record_to=tmp_path / "raw",
                                     notes=notes)
    assert isinstance(error, DeviceChanged) and "OTHER-9999" in str(error)
    assert "hostile-0001" in str(error) and "\n" not in str(error)
    # At once, from the stream (issue 40: it said "stopping", reconnected, then failed).
    assert "while streaming" in str(error) and notes == [], (str(error), notes)
    ours = [seq for seq, counts in board.sent if counts[0] != 777]
    assert [r["seq"] for r in records if "seq" in r] == ours[TARE:]
    log = read_log(tmp_path / "raw" / "acquisition.log")
    kept = [f for a in log.completed.values() for f in a.frames]
    assert [f.seq for f in kept] == ours and all(f.counts[0] != 777 for f in kept)


@pytest.mark.parametrize(("misbehaviour", "says"), [
    ("stream_junk", "no valid frame"),
    ("stream_cr_only", "lines end in CR only"),
])
@pytest.mark.heavy
def test_live_gives_up_on_a_board_that_streams_only_junk(stack, misbehaviour, says):
    """Issue 40, finding 5: junk counted as progress, so a board that streamed a junk line
    every few seconds, or lines ending in CR only, had live print {"rejected": ...}
    forever. Now, no valid frame for the timeout plus the reconnect budget: one line."""
    from eskin.errors import EskinError

    _, skin = stack
    timeout_s, reconnect_s = 0.5, 1.0
    started = time.monotonic()
    records, error = live_on_hostile(skin, HostileBoard(misbehaviour=misbehaviour, at=80),
                                     wanted=10_000, timeout_s=timeout_s,
                                     reconnect_s=reconnect_s, wall_s=20.0)
    seconds = time.monotonic() - started
    assert isinstance(error, EskinError), (error, records[-3:])
    assert says in str(error) and "\n" not in str(error), str(error)
    assert seconds < 2 * timeout_s + 2 * reconnect_s + 3, seconds
    assert sum("seq" in r for r in records) == 80 - 1 - TARE  # all it streamed, predicted


@pytest.mark.heavy
def test_a_streamed_frame_whose_board_time_fell_is_reported_never_predicted(stack):
    """Issue 40, finding 3, live: a frame whose t_ms fell (its CRC-8 matched by chance)."""
    _, skin = stack
    board = HostileBoard(misbehaviour="stream_time_back", at=120)
    records, error = live_on_hostile(skin, board, wanted=150)
    assert error is None and len(board.time_back) == 1
    predicted = [r["seq"] for r in records if "seq" in r]
    assert board.time_back[0] not in predicted and len(predicted) == 150
    assert any("board time went backwards" in r.get("rejected", "") for r in records)


@pytest.mark.heavy
def test_a_damaged_line_and_a_lost_frame_are_reported_and_never_predicted(stack):
    params, skin = stack
    events, records = run_live(params, skin, corrupt_fraction=0.05, estimates_wanted=150)
    rejected = [r for r in records if "rejected" in r]
    gaps = [r["gap"] for r in records if "gap" in r]
    assert rejected and gaps
    predicted = {r["seq"] for r in records if "seq" in r}
    lost = {seq for gap in gaps for seq in range(gap["expected"], gap["got"])}
    assert lost and not lost & predicted
    assert len(predicted) == len([r for r in records if "seq" in r])


def test_the_host_protocol_marks_streamed_frames_and_gaps_until_the_fence():
    """Sans-I/O: after #OK STREAM ON, frames are StreamFrame and a lost seq a StreamGap;
    the STREAM OFF fence's #OK ends the stream."""
    protocol = HostProtocol(device_id="b")
    protocol.send_stream()
    events = protocol.receive(b"#OK STREAM ON\n")
    assert protocol.streaming and events
    events = protocol.receive(encode_frame(7, 84, [500] * 20) + encode_frame(9, 108, [500] * 20))
    assert [type(e) for e in events] == [StreamFrame, StreamGap, StreamFrame]
    protocol.send_fence()
    protocol.receive(b"#OK STREAM OFF\n")
    assert not protocol.streaming


def test_a_stack_for_another_board_is_refused_in_one_line(stack):
    _, skin = stack
    with pytest.raises(StackError, match="trained on device sim-.*, but the board says it is "
                       "lab2-skin1: acquire and train on this board"):
        skin.check_board("lab2-skin1")


def test_the_json_lines_reach_a_client_on_loopback_and_a_stalled_one_is_dropped():
    import socket

    notes = []
    # The kernel buffers several MB for a client on loopback before the backlog grows.
    with LineBroadcast(0, max_backlog=1 << 20, notify=notes.append) as broadcast:
        reader = socket.create_connection(("127.0.0.1", broadcast.port), timeout=5)
        stalled = socket.create_connection(("127.0.0.1", broadcast.port), timeout=5)
        stalled.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        received = bytearray()
        lines = [json_line({"seq": i, "note": "x" * 500}) for i in range(40_000)]  # 20 MB
        for line in lines:
            broadcast.send(line)
            with contextlib.suppress(BlockingIOError):
                reader.setblocking(False)
                received += reader.recv(1 << 16)
        reader.setblocking(True)
        reader.settimeout(2)
        with contextlib.suppress(TimeoutError):
            while received.count(b"\n") < len(lines):
                received += reader.recv(1 << 16)
        assert received.decode().splitlines() == lines
        assert any("dropped: more than 1048576 bytes unread" in note for note in notes)
        reader.close()
        stalled.close()


@needs_chromium
@pytest.mark.starts
def test_the_live_view_shows_a_press_where_and_as_hard_as_it_is(stack, tmp_path):
    """The page in headless Chromium, read as a person reads it, while the live loop runs
    on the simulated board's stream and a weight is pressed on node (5, 5)."""
    params, skin = stack
    settings = typed(params).acquire
    stop, failure = threading.Event(), []

    def loop(view):
        try:
            with contextlib.ExitStack() as resources:
                board = resources.enter_context(simulated_board(
                    skin_params(typed(params).sim), rest_length_mm=float(settings.rest_length_mm),
                    frame_period_ms=12))
                link = resources.enter_context(SerialLink(board.port, timeout_s=5.0))
                link.connect()
                stream = resources.enter_context(contextlib.closing(stream_events(link)))
                estimates = 0
                for record in live_estimates(skin, stream, tare_frames=TARE, with_change=True):
                    view.show(record)
                    estimates += "seq" in record
                    if estimates == 30:
                        link.command("SIM PRESS 5 5 3.2536")
                    if stop.is_set() or estimates > 3000:
                        return
        except Exception as err:  # noqa: BLE001 - reported by the test below
            failure.append(err)

    with LiveView(scene="single_force", kind="single_force", device="sim",
                  skin=PAPER_SKIN) as view:
        worker = threading.Thread(target=loop, args=(view,), daemon=True)
        worker.start()
        try:
            with headless_chromium() as browser:
                page = browser.new_page(viewport={"width": 980, "height": 640})
                page.goto(view.url)
                page.wait_for_function(
                    "document.getElementById('location').textContent === 'x 5, y 5'",
                    timeout=30_000)
                shown = {name: page.inner_text(f"#{name}")
                         for name in ("contact", "force", "stretch", "seq", "rate")}
                cell = page.inner_text("#cell-5-5")
                bar = page.eval_on_selector("#bar-x5", "bar => bar.style.height")
                scale = {name: page.inner_text(f"#{name}")
                         for name in ("tick-top", "tick-middle", "channels")}
                page.screenshot(path=str(tmp_path / "live_view.png"))
        finally:
            stop.set()
            worker.join(timeout=30)
    assert not failure, failure
    assert shown["contact"].startswith("touch (p = ")
    assert abs(float(shown["force"].removesuffix(" N")) - 3.2536) < 0.5
    assert cell.endswith(" N") and abs(float(cell.removesuffix(" N")) - 3.2536) < 0.5
    assert abs(float(shown["stretch"]) - 1.0) < 0.02
    assert 60 < float(shown["rate"]) < 100  # the board's 12 ms frames: 83 a second
    # x5 carries the press: above half of the axis, a round number of ADC counts
    assert float(bar.removesuffix("%")) > 50
    assert scale["tick-top"] in ("50", "100", "200") and "in ADC counts" in scale["channels"]
    assert float(scale["tick-middle"]) == float(scale["tick-top"]) / 2


def test_stream_events_beyond_the_backlog_kept_during_a_command_are_reported(stack):
    """Frames that arrive while a command is answered wait for the stream in a bounded
    backlog; those that do not fit are counted and reported, never silently gone."""
    import collections
    import time

    from eskin.device.link import StreamOverflow

    params, _ = stack
    with simulated_board(skin_params(typed(params).sim), rest_length_mm=101.0,
                         frame_period_ms=4) as board, SerialLink(board.port) as link:
        link.connect()
        link._backlog = collections.deque(maxlen=5)  # instead of STREAM_BACKLOG's 4,096
        link.start_stream()
        time.sleep(0.3)  # about 75 frames pile up before the command reads them
        link.command("SIM CLEAR")
        first = next(link.stream())
        link.stop_stream()
    assert isinstance(first[0], StreamOverflow) and first[0].dropped > 20
    frames = [e for e in first[1:6] if isinstance(e, StreamFrame)]
    assert len(frames) == 5 and [f.frame.seq for f in frames] == list(
        range(frames[0].frame.seq, frames[0].frame.seq + 5))


def test_without_a_tare_there_is_no_drift_or_change_to_report(stack):
    """--tare-frames 0: nothing to measure drift or change from, so both are null (not
    the raw counts' distance from zero)."""
    from eskin.device.protocol import parse_line

    _, skin = stack
    frames = [StreamFrame(parse_line(encode_frame(seq, 12 * seq, [400] * 20).rstrip(b"\n")))
              for seq in range(3)]
    records = list(live_estimates(skin, [frames], tare_frames=0, with_change=True))
    assert [r["seq"] for r in records] == [0, 1, 2]
    assert all(r["drift_counts"] is None and r["change_counts"] is None for r in records)


# --- Pressing the simulated skin from the view, and from the terminal (issue 53) --------


@pytest.fixture(scope="module")
def live_view(stack, tmp_path_factory):
    """`eskin live single_force --simulated --view 0` in its own process, as a user runs
    it, on the small stack (exported): the view's port, once it shows frames."""
    _, skin = stack
    onnx = write_stack(skin, tmp_path_factory.mktemp("press") / "stack.onnx", sources={})
    process = subprocess.Popen(
        [sys.executable, "-m", "eskin", "live", "single_force", "--simulated", "--onnx",
         str(onnx), "--view", "0", "--quiet", "--tare-frames", str(TARE)],
        cwd=ROOT, stderr=subprocess.PIPE, text=True)
    said: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [said.put(line) for line in process.stderr],
                     daemon=True).start()
    lines, port = [], None
    try:
        deadline = time.monotonic() + 120
        while port is None:
            line = said.get(timeout=max(0.1, deadline - time.monotonic()))
            lines.append(line)
            if "the live view is at " in line:
                port = int(line.split("http://127.0.0.1:")[1].split("/")[0])
        while view_state(port)["estimate"] is None:  # the tare's frames first
            assert time.monotonic() < deadline, lines
            time.sleep(0.2)
        yield port, lines
    finally:
        process.terminate()
        process.wait(timeout=30)
    assert process.returncode in (0, 128 + 15), lines


def view_state(port: int) -> dict:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/state", timeout=5) as answer:
        return json.loads(answer.read())


def eskin(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "eskin", *args], cwd=ROOT, text=True,
                          capture_output=True, timeout=120)


def wait_for_estimate(port: int, wanted, seconds: float = 30.0) -> dict:
    """The first estimate the view serves for which ``wanted`` holds."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        estimate = view_state(port)["estimate"]
        if wanted(estimate):
            return estimate
        time.sleep(0.1)
    raise AssertionError(f"no such estimate within {seconds} s; the last: {estimate}")


@needs_chromium
@pytest.mark.starts
def test_a_click_on_the_view_presses_the_simulated_skin_there_with_the_weight_set(
        live_view, tmp_path):
    """A newcomer's case: set a weight on the page, click node (6, 4), see the contact
    there and about that heavy; click it again, and the weight is lifted."""
    port, _ = live_view
    chosen = 3.2536  # the small scene's weight; the page offers 5.2136 (params.yaml's)
    with headless_chromium() as browser:
        page = browser.new_page(viewport={"width": 1400, "height": 900})
        page.goto(f"http://127.0.0.1:{port}/")
        page.wait_for_function("document.getElementById('seq').textContent !== '–'",
                               timeout=30_000)
        offered = page.input_value("#weight")
        assert page.inner_text("#contact").startswith("no touch")
        page.fill("#weight", str(chosen))
        page.click("#cell-6-4")
        page.wait_for_function(
            "document.getElementById('location').textContent === 'x 6, y 4'", timeout=30_000)
        time.sleep(0.5)  # the ramp's 100 ms, and a few frames at the full load
        shown = {name: page.inner_text(f"#{name}") for name in ("contact", "force", "pressed")}
        cell = page.inner_text("#cell-6-4")
        outlined = page.eval_on_selector("#cell-6-4", "cell => cell.classList.contains('pressed')")
        # both ticks in one call: the page redraws them together, and could between two
        ticks = page.evaluate("['top', 'middle'].map(name => "
                              "document.getElementById(`tick-${name}`).innerText)")
        bars = page.eval_on_selector_all(
            "#bars div", "bars => bars.map(bar => [bar.id, bar.style.height, bar.title])")
        caption = page.inner_text("#channels figcaption")
        page.screenshot(path=str(tmp_path / "live_press.png"))
        page.click("#cell-6-4")  # again: lifted
        page.wait_for_function(
            "document.getElementById('contact').textContent.startsWith('no touch')",
            timeout=30_000)
        after = page.inner_text("#pressed")
    assert offered == "5.2136"  # the scene's heaviest level
    assert shown["contact"].startswith("touch (p = ")
    assert abs(float(shown["force"].removesuffix(" N")) - chosen) < 0.5
    assert shown["pressed"] == f"{chosen} N on x 6, y 4" and outlined
    assert cell.endswith(" N") and abs(float(cell.removesuffix(" N")) - chosen) < 0.5
    # The bars on their axis: a round number of ADC counts at the top, each bar as tall
    # as its change is on that axis, the tallest of the rows and of the columns by the
    # pressed node.
    assert "ADC counts" in caption
    top, middle = (float(tick) for tick in ticks)
    assert top in (20, 50, 100, 200, 500, 1000) and middle == top / 2
    counts = {name.removeprefix("bar-"): float(title.split(": ")[1].removesuffix(" counts"))
              for name, _, title in bars}
    for name, height, _ in bars:
        assert abs(float(height.removesuffix("%")) - abs(counts[name[4:]]) / top * 100) < 0.01
    assert max(map(abs, counts.values())) <= top < 2.5 * max(map(abs, counts.values()))
    assert max((c for c in counts if c.startswith("x")), key=counts.get) in ("x5", "x6", "x7")
    assert max((c for c in counts if c.startswith("y")), key=counts.get) in ("y3", "y4", "y5")
    assert after == "nothing pressed" and view_state(port)["pressed"] == []


@pytest.mark.heavy
def test_eskin_press_presses_the_running_view_and_releases(live_view):
    port, _ = live_view
    done = eskin("press", "2", "8", "3.2536", "--view", str(port))
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "pressed: 3.2536 N on x 2, y 8"
    assert view_state(port)["pressed"] == [{"x": 2, "y": 8, "force_n": 3.2536}]
    estimate = wait_for_estimate(port, lambda e: e["contact"] and (e["x"], e["y"]) == (2, 8))
    assert abs(estimate["force"] - 3.2536) < 0.5
    done = eskin("press", "--release", "--view", str(port))
    assert (done.returncode, done.stdout.strip()) == (0, "pressed: nothing"), done.stderr
    wait_for_estimate(port, lambda e: not e["contact"])


def test_eskin_press_off_the_skin_is_refused_by_the_view_in_one_line(live_view):
    port, _ = live_view
    done = eskin("press", "11", "4", "3.2", "--view", str(port))
    assert done.returncode == 1 and done.stdout == ""
    assert done.stderr == (f"eskin: error: the live view on 127.0.0.1:{port}: x 11 is no "
                           "node of the 10 × 10 row/column skin (20 terminals): x is a whole "
                           "number 1..10\n")
    assert view_state(port)["pressed"] == []


def test_eskin_press_with_no_view_running_says_so_in_one_line():
    with socket.socket() as free:  # a port nothing listens on
        free.bind(("127.0.0.1", 0))
        port = free.getsockname()[1]
    done = eskin("press", "6", "4", "5.2", "--view", str(port))
    assert done.returncode == 1 and done.stdout == ""
    assert done.stderr.startswith(f"eskin: error: no live view on 127.0.0.1:{port} ")
    assert f"eskin live <scene> --simulated --view {port}" in done.stderr
    assert done.stderr.count("\n") == 1


@needs_chromium
@pytest.mark.starts
def test_a_view_of_a_real_board_offers_no_pressing_and_says_why():
    """No pressing on a real board: the page says why, and POST /press is refused."""
    with LiveView(scene="single_force", kind="single_force", device="lab2-skin1",
                  skin=PAPER_SKIN) as view:
        with headless_chromium() as browser:
            page = browser.new_page()
            page.goto(view.url)
            why = page.inner_text("#press-off")
            controls = page.query_selector_all("#weight, #release")
            page.click("#cell-6-4")  # nothing happens
            pressable = page.eval_on_selector("#map", "map => map.classList.contains('pressable')")
        request = urllib.request.Request(f"{view.url}press", method="POST",
                                         data=b'{"x": 6, "y": 4, "force_n": 5.2}')
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(request, timeout=5)
        assert view.requests() == [] and view._presses == []
    assert "needs the simulated board" in why and "by hand" in why
    assert controls == [] and not pressable
    assert refused.value.code == 409
    assert "real board" in json.loads(refused.value.read())["error"]



# --- The page's layout, from 2 × 2 to 32 × 32 in a 1,280 px window (issue 59) ---------


def assert_laid_out(layout: dict, width: int) -> None:
    """Nothing of the page beyond ``width``: no horizontal scroll, the status column whole,
    every bar and node cell inside, no two cells overlapping, no two labels shown either."""
    assert layout["width"] == width and layout["scroll_width"] <= width
    left, right, _, _ = layout["readout"]
    assert 0 <= left < right <= width and layout["readout_hidden"] == 0
    for name in ("bars", "bar_labels", "x_labels", "y_labels"):
        placed = np.array(layout[name])
        assert (placed[:, 0] >= 0).all() and (placed[:, 1] <= width).all(), name
    assert (np.diff(np.array(layout["bars"])[:, 1]) > 0).all()  # side by side, in order
    cells = np.array(list(layout["cells"].values()))
    assert (cells[:, 0] >= 0).all() and (cells[:, 1] <= width).all()
    assert (cells[:, 1] - cells[:, 0] >= 12).all()  # still a target for a click
    for boxes, name in ((cells, "cells"), (np.array(layout["bar_labels"]), "bar labels"),
                        (np.array(layout["x_labels"]), "x labels"),
                        (np.array(layout["y_labels"]), "y labels")):
        (l1, l2), (r1, r2), (t1, t2), (b1, b2) = (
            np.meshgrid(boxes[:, side], boxes[:, side], indexing="ij") for side in range(4))
        overlap = (np.maximum(l1, l2) < np.minimum(r1, r2)) \
            & (np.maximum(t1, t2) < np.minimum(b1, b2))
        assert not overlap[~np.eye(len(boxes), dtype=bool)].any(), name


@needs_chromium
@pytest.mark.starts
@pytest.mark.parametrize(("rows", "columns"), [(2, 2), (10, 10), (16, 12), (32, 32)])
def test_the_live_view_lays_out_any_skin_up_to_32_by_32_in_1280_px(repo_params, rows,
                                                                     columns):
    """The page of an R × C skin at 1280 × 800 in headless Chromium, read back from the
    DOM, while the skin's simulated board streams; a click on the far corner node
    (R, C) lays the weight there, and the board's frames change most by it."""
    from harness.live_view_layout import LAYOUT, pressed_page, view_on_the_board

    skin = Skin(rows, columns)
    with view_on_the_board(typed(repo_params), skin) as (view, failure), \
            headless_chromium() as browser:
        page = pressed_page(browser, view, (rows, columns))
        layout = page.evaluate(LAYOUT)
        outlined = page.eval_on_selector(f"#cell-{rows}-{columns}",
                                         "cell => cell.classList.contains('pressed')")
        change = view_state(view.port)["estimate"]["change_counts"]
        pressed = view_state(view.port)["pressed"]
    assert not failure, failure
    assert_laid_out(layout, 1280)
    assert len(layout["cells"]) == rows * columns and len(layout["bars"]) == rows + columns
    if rows * columns <= 16 * 12:  # as before the layout grew: 2.6em cells, 30 px bars
        assert all(abs(right - left - 41.6) < 0.1 for left, right, _, _ in layout["cells"].values())
        assert all(abs(right - left - 30) < 0.1 for left, right, _, _ in layout["bars"])
        assert len(layout["bar_labels"]) == rows + columns
    else:  # x1, x3, .. y1, y3, ..: every other label of each run
        assert len(layout["bar_labels"]) == (rows + 1) // 2 + (columns + 1) // 2
    assert outlined and pressed == [{"x": rows, "y": columns, "force_n": 5.0}]
    assert int(np.argmax(change[:rows])) + 1 in (rows - 1, rows)
    assert int(np.argmax(change[rows:])) + 1 in (columns - 1, columns)


@needs_chromium
@pytest.mark.starts
def test_a_channel_arrays_live_view_is_laid_out_in_1280_px_with_its_own_names():
    """A skin given by its channels: 40 named channels on an 8 × 5 grid of positions, their
    bars labelled with their names (every other one: they are long), the contact marked."""
    from harness.live_view_layout import LAYOUT

    skin = ChannelArray(tuple(f"taxel{i:02d}" for i in range(1, 41)), 8, 5)
    with LiveView(scene="array", kind="single_force", device="lab", skin=skin) as view, \
            headless_chromium() as browser:
        view.show({"seq": 1, "t_ms": 12, "x": 7, "y": 2, "force": 2.5, "contact": True,
                   "contact_probability": 0.9, "stretch": 1.0, "drift_counts": 0.0,
                   "change_counts": [float(i) for i in range(40)]})
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        page.goto(view.url)
        page.wait_for_function("document.getElementById('location').textContent === 'x 7, y 2'",
                               timeout=30_000)
        layout = page.evaluate(LAYOUT)
        labels = page.eval_on_selector_all(
            "#barlabels div", "labels => labels.filter(l => getComputedStyle(l).visibility"
            " !== 'hidden').map(l => l.textContent)")
        cell = page.inner_text("#cell-7-2")
    assert_laid_out(layout, 1280)
    assert len(layout["cells"]) == 40 and len(layout["bars"]) == 40
    assert labels == [f"taxel{i:02d}" for i in range(1, 41, 2)]
    assert cell == "2.5 N"


def ask(view: LiveView, body: dict, send) -> list | PressRefused:
    """``POST /press``'s part on the server's thread, the loop's on this one (``send``
    standing for the link): what the requester is answered."""
    outcome: list = []

    def request() -> None:
        try:
            outcome.append(view.press(json.dumps(body).encode(), wait_s=10))
        except PressRefused as err:
            outcome.append(err)

    asker = threading.Thread(target=request)
    asker.start()
    while not view._presses and asker.is_alive():
        time.sleep(0.01)
    view.carry_out_presses(send)
    asker.join()
    return outcome[0]


def test_press_requests_become_the_simulated_boards_commands():
    """Carried out on the loop's side: none during the tare; a weight laid, a second one
    on a two-contact skin, a third lifts the oldest, one lifted, all lifted; and one the
    board refuses is told to its requester."""
    from eskin.errors import EskinError

    sent: list[str] = []
    with LiveView(scene="two_force", kind="two_force", device="sim", skin=PAPER_SKIN,
                  pressing=Pressing.of_scene([1.2936, 5.2136], contacts=2, max_n=50)) as view:
        taring = ask(view, {"x": 6, "y": 4, "force_n": 5.2136}, sent.append)
        view.show({"seq": 1, "t_ms": 12})  # frames are shown: the tare is over
        answers = [ask(view, body, sent.append) for body in (
            {"x": 6, "y": 4, "force_n": 5.2136}, {"x": 2, "y": 9, "force_n": 1.2936},
            {"x": 7, "y": 7, "force_n": 3.0}, {"x": 2, "y": 9, "release": True},
            {"release": True})]
        wrong = [ask(view, body, sent.append) for body in (
            {"x": 6, "y": 4, "force_n": 0}, {"x": 6, "y": 4, "force_n": 51},
            {"x": 0, "y": 4, "force_n": 1}, {"x": 6, "y": 4.5, "force_n": 1}, ["release"])]

        tried: list[str] = []

        def refuse(command: str) -> None:
            tried.append(command)
            if command.startswith("SIM PRESS"):
                raise EskinError(f"#ERR SIM refused {command!r}")

        refused = ask(view, {"x": 1, "y": 1, "force_n": 2}, refuse)
        pressed = json.loads(view.state_json())["pressed"]
    assert isinstance(taring, PressRefused) and taring.status == 409
    assert "tare" in str(taring)
    weight = {"x": 6, "y": 4, "force_n": 5.2136}
    light, third = {"x": 2, "y": 9, "force_n": 1.2936}, {"x": 7, "y": 7, "force_n": 3.0}
    assert answers == [[weight], [weight, light], [light, third], [third], []]
    assert sent == ["SIM CLEAR", "SIM PRESS 6 4 5.2136 100",
                    "SIM CLEAR", "SIM PRESS 6 4 5.2136", "SIM PRESS 2 9 1.2936 100",
                    "SIM CLEAR", "SIM PRESS 2 9 1.2936", "SIM PRESS 7 7 3.0 100",
                    "SIM CLEAR", "SIM PRESS 7 7 3.0",
                    "SIM CLEAR"]
    assert [(w.status, str(w).split(":")[0].split(" ")[0]) for w in wrong] == [
        (400, "force_n"), (400, "force_n"), (400, "x"), (400, "y"), (400, "not")]
    assert refused.status == 502 and "#ERR SIM refused 'SIM PRESS 1 1 2.0 100'" in str(refused)
    assert tried == ["SIM CLEAR", "SIM PRESS 1 1 2.0 100"] and pressed == []  # cleared


ONE_THREAD_PROBE = """
import json
import eskin.deploy.stack as stack_module  # first, as `eskin live` imports it
import numpy as np
from threadpoolctl import threadpool_info
from sklearn.ensemble import HistGradientBoostingRegressor  # the models' OpenMP, loaded now
from eskin.skin import PAPER_SKIN, ChannelArray, Skin

class Identity:
    def transform(self, X):
        return X

class Spy:
    threads = []
    def predict(self, X):
        Spy.threads.append([p["num_threads"] for p in threadpool_info()
                            if p["user_api"] == "openmp"])
        return np.zeros(len(X))

spy = Spy()
stack = stack_module.SkinStack("s", "single_force", PAPER_SKIN, Identity(),
                               {"stretch": {"stretch": spy}})
stack.predict(np.zeros((1, 20)))
stack.predict(np.zeros((stack_module.ONE_THREAD_ROWS + 1, 20)))
print(json.dumps(Spy.threads))
"""


def test_a_few_frames_are_predicted_on_one_openmp_thread_without_omp_num_threads():
    """Issue 57, finding 4: the one-thread guard's ThreadpoolController was made at import,
    before scikit-learn's OpenMP library loaded, and limited nothing: at load 15, 267 ms a
    frame (79 ms with it). The tests set OMP_NUM_THREADS=1 under xdist, which hid it: here
    a process without it, on a machine with two cores or more (else nothing to limit)."""
    import os

    if (os.cpu_count() or 1) < 2:
        pytest.skip("one core: OpenMP has one thread anyway")
    env = {k: v for k, v in os.environ.items() if k != "OMP_NUM_THREADS"}
    out = subprocess.run([sys.executable, "-c", ONE_THREAD_PROBE], env=env, cwd=ROOT,
                         capture_output=True, text=True, timeout=120, check=True).stdout
    few, many = json.loads(out.splitlines()[-1])
    assert few and all(n == 1 for n in few), few  # a frame: one thread
    assert many and all(n > 1 for n in many), many  # a large batch: OpenMP's own
