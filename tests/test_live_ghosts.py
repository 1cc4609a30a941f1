"""Issue 39: the live stack on the simulated skin, as `eskin live single_force --simulated`
runs it (the same board, skin and 12 ms frames), streamed faster than real time
(:func:`eskin.device.simulate.accelerated_stream`): no phantom contacts on an untouched
skin, a sustained press still seen at its end, a re-tare over the JSON socket, and no
flicker. On the default models trained on the small single-force scene."""

from __future__ import annotations

import json
import socket

import numpy as np
import pytest

from eskin.config.base import load_params
from eskin.config.live import Live
from eskin.config.params import Params
from eskin.deploy.export import write_stack
from eskin.deploy.live import ContactHysteresis, LineBroadcast, live_estimates
from eskin.deploy.stack import ExportedStack
from eskin.device.board import SimulatedBoard
from eskin.device.simulate import accelerated_stream, live_board
from eskin.skin import PAPER_SKIN
from harness.live_view_shot import sustained_press_on_the_view
from tests.conftest import headless_chromium, needs_chromium, small_scenes, small_stack

TEN_MINUTES = 10 * 60 * 1000 // 12  # frames at the board's 12 ms period: 50,000


@pytest.fixture(scope="module")
def params():
    return load_params(Params)


@pytest.fixture(scope="module")
def sklearn(tmp_path_factory, repo_params):
    """The default models of the single-force scene, trained on the small scene (a fresh
    clone has no workspace models, and the pipeline's take minutes)."""
    return small_stack(small_scenes(repo_params), tmp_path_factory.mktemp("ghosts"))


@pytest.fixture(scope="module")
def onnx(sklearn, tmp_path_factory):
    return ExportedStack.from_file(write_stack(
        sklearn, tmp_path_factory.mktemp("onnx") / "stack.onnx", sources={}))


def board(params) -> SimulatedBoard:
    """The board `eskin live --simulated` starts (eskin/cli.py)."""
    return live_board(params, PAPER_SKIN)


def run(stack, params, frames: int, *, batch: int, script=(), settings=None, requests=tuple,
        with_change=False):
    """The live estimates of ``frames`` streamed frames (after the tare's); ``script`` is
    (estimates out, board command) pairs, sent while the board streams."""
    sim, script, records = board(params), list(script), []
    estimates = 0

    def batches():
        for events in accelerated_stream(sim, batch_frames=batch):
            while script and estimates >= script[0][0]:
                sim.handle(script.pop(0)[1].encode())
            yield events

    for record in live_estimates(stack, batches(), settings=settings or params.live,
                                 requests=requests, with_change=with_change):
        records.append(record)
        estimates += "seq" in record
        if estimates >= frames:
            break
    return records


def contact_share(records) -> float:
    return float(np.mean([r["contact"] for r in records if "seq" in r]))


@pytest.mark.heavy
def test_ten_untouched_minutes_give_no_more_than_a_tenth_of_a_percent_contact(params, onnx):
    """The new user's case: nothing pressed for 10 minutes. On HEAD before issue 39 (an
    unbounded drift, one tare at start, nothing followed) the ONNX stack saw contact on
    98.9 % of the frames."""
    records = run(onnx, params, TEN_MINUTES, batch=8)
    estimates = [r for r in records if "seq" in r]
    assert len(estimates) == TEN_MINUTES
    assert contact_share(records) <= 0.001
    # the skin drifted, as a real one does, and live followed it: bounded (σ 0.02 pF is
    # about one count; the unbounded walk of before had moved it 60 counts by now)
    followed = [r["drift_counts"] for r in estimates]
    assert 0 < max(followed) < 10


def test_the_scikit_learn_stack_live_gives_the_onnx_stacks_contact(params, onnx, sklearn):
    """Hysteresis and tracking are live's, on either stack's outputs: the same stream
    (untouched, a press, untouched) gives the same contact frame by frame. (10 minutes of
    the scikit-learn stack take minutes here: the ONNX stack stands for both above.)"""
    script = [(200, "SIM PRESS 3 7 3.2536"), (450, "SIM CLEAR")]
    both = [[r["contact"] for r in run(stack, params, 700, batch=32, script=script)
             if "seq" in r] for stack in (onnx, sklearn)]
    assert both[0] == both[1]
    # one contact, from the press (sent between batches of 32 frames, then 50 ms of
    # hysteresis) to its release
    began, ended = np.flatnonzero(np.diff(both[0])) + 1
    assert 200 <= began < 300 and 450 <= ended < 700


def test_a_re_tare_on_a_stretched_skin_takes_off_drift_not_the_stretch(params, onnx):
    """A tare once mapped its reading to the training rest, which is unstretched:
    re-tared at a stretch, live took the stretched skin for a relaxed one, and back at
    rest it read λ 0.92 and missed every press (the live hour, before). A tare now reads
    the stretch the skin is at from its channels, and takes only the offset from the
    training's untouched reading there. (8 mm: the small test scene's largest stretch.)"""
    asked = iter([False] * 40 + [True])  # the request once the stretch has settled

    def requests():
        return ["tare"] if next(asked, False) else []

    script = [(100, "STRETCH 8"), (1500, "STRETCH 0"), (2000, "SIM PRESS 5 5 3.2536")]
    records = run(onnx, params, 2400, batch=8, script=script, requests=requests)
    assert [r["tare"]["reason"] for r in records if "tare" in r] == ["start", "request"]
    estimates = [r for r in records if "seq" in r]
    stretched = [r["stretch"] for r in estimates[1200:1450]]
    relaxed = [r["stretch"] for r in estimates[1700:1950]]
    assert np.median(stretched) == pytest.approx(1 + 8 / 101, abs=0.02)
    assert np.median(relaxed) == pytest.approx(1.0, abs=0.02)
    assert not any(r["contact"] for r in estimates[:2000])
    pressed = estimates[2100:]
    assert all(r["contact"] for r in pressed)
    assert {(r["x"], r["y"]) for r in pressed} == {(5, 5)}


@pytest.mark.heavy
def test_a_two_minute_press_is_still_seen_at_its_end(params, onnx):
    untouched, pressed = 1000, 10_000  # 12 s, then 2 minutes
    records = run(onnx, params, untouched + pressed, batch=8, with_change=True,
                  script=[(untouched, "SIM PRESS 5 5 3.2536")])
    estimates = [r for r in records if "seq" in r]
    assert not any(r["contact"] for r in estimates[:untouched])
    end = estimates[-250:]  # its last 3 s
    assert all(r["contact"] for r in end)
    # where and about how hard: the drift is bounded, and creep (5 % of the strain, over
    # 10 s) makes a held press read a little stronger, not weaker
    assert {(r["x"], r["y"]) for r in end} == {(5, 5)}
    assert np.median([r["force"] for r in end]) == pytest.approx(3.2536, abs=1.0)
    # A contact's own channels are frozen (live.baseline.in_contact): the pressed
    # terminals' change from the expected untouched reading is the press's, at its start
    # and at its end, not absorbed.
    start, last = estimates[untouched + 50]["change_counts"], estimates[-1]["change_counts"]
    for terminal in (4, 14):  # x5, y5: a press of about 20 counts, creeping up, not down
        assert start[terminal] > 10 and last[terminal] > start[terminal] - 3


def test_a_client_of_the_json_socket_re_tares_and_a_bad_line_is_answered(params, onnx):
    with LineBroadcast(0) as broadcast:
        client = socket.create_connection(("127.0.0.1", broadcast.port), timeout=5)
        client.sendall(b'{"command": "tare"}\n{"command": "dance"}\nnot json\n')
        asked: list[str] = []
        batches = iter(range(1_000_000))

        def requests():  # read once the start tare (50 frames, 7 batches) is done
            if next(batches) < 20:
                return []
            got = broadcast.requests()
            asked.extend(got)
            return got

        records = run(onnx, params, 600, batch=8, settings=Live(tare_frames=50),
                      requests=requests)
        for record in records:
            broadcast.send(json.dumps(record))
        client.settimeout(2)
        received = b""
        while received.count(b"\n") < 2:
            received += client.recv(1 << 16)
        client.close()
    tares = [r["tare"] for r in records if "tare" in r]
    assert asked == ["tare"]
    assert [t["reason"] for t in tares] == ["start", "request"]
    assert all(t["frames"] == 50 for t in tares)
    errors = [json.loads(line) for line in received.splitlines()[:2]]
    assert "unknown command 'dance'" in errors[0]["error"]
    assert "not a JSON line" in errors[1]["error"]


def test_hysteresis_turns_a_flickering_probability_into_one_contact():
    """A detector near its threshold: p alternates around 0.5 every frame for a second,
    then stays high. The stack's own verdict flips 80 times; with hysteresis contact
    begins once, after the minimum duration of steady high p, and does not flicker."""
    hysteresis = ContactHysteresis(enter=0.8, leave=0.5, min_duration_ms=50)
    flicker = [0.85, 0.45] * 40
    probabilities = flicker + [0.95] * 20 + [0.6, 0.3, 0.7] * 10 + [0.1] * 10
    verdicts = [hysteresis.update(p, 12 * i) for i, p in enumerate(probabilities)]
    changes = np.flatnonzero(np.diff(verdicts))
    assert np.count_nonzero(np.diff([p >= 0.5 for p in probabilities])) > 60
    assert not any(verdicts[:80])
    assert len(changes) == 2  # on once, off once
    assert changes[0] + 1 == 80 + 5  # 50 ms of high p at 12 ms a frame: its sixth frame
    assert all(verdicts[100:130])  # between the thresholds it stays in contact
    assert not verdicts[-1]


def test_a_typo_in_the_live_knobs_is_one_line_naming_the_key():
    import yaml

    from eskin.config.base import ParamsError, validate_params

    params = yaml.safe_load(open("params.yaml", encoding="utf-8"))
    params["live"]["baseline"]["gate_count"] = params["live"]["baseline"].pop("gate_counts")
    with pytest.raises(ParamsError, match=r"live\.baseline\.gate_count is not a known key; "
                       r"did you mean live\.baseline\.gate_counts\?"):
        validate_params(params, Params)
    params["live"]["baseline"]["gate_counts"] = params["live"]["baseline"].pop("gate_count")
    params["live"]["contact"]["leave_probability"] = 0.95
    with pytest.raises(ParamsError, match="leave_probability .* is above enter_probability"):
        validate_params(params, Params)


@needs_chromium
@pytest.mark.starts
def test_the_view_during_a_sustained_press_and_its_re_tare_button(params, onnx, tmp_path):
    """Two minutes of a 3.3 N press on node (5, 5), read off the page in headless
    Chromium at its end (and photographed); then the weight is lifted and the page's
    re-tare button clicked: the live loop takes a tare on request, and the page says so."""
    with headless_chromium() as browser:
        shown = sustained_press_on_the_view(onnx, params, browser, tmp_path / "view.png",
                                            press=((5, 5, 3.2536),))
    assert shown["contact"].startswith("touch (p = ")
    assert shown["location"] == "x 5, y 5"
    assert abs(float(shown["force"].removesuffix(" N")) - 3.2536) < 1.0
    assert (tmp_path / "view.png").stat().st_size > 10_000
    assert shown["tared"].startswith("again at frame") and "on 100 frames" in shown["tared"]


# A real capacitive skin's drift (issue 57): 0.17–0.28 pF over hours, 0.0032 pF/√s; the
# simulator's per-terminal drift at SD 0.04 pF spans that range. Its own parameter here,
# not params.yaml's sim (whose change would redraw every dataset).
REAL_DRIFT_PF = 0.04


def real_drift_board(params, wait_s: float) -> SimulatedBoard:
    """The live board with real-sized drift, ``wait_s`` of board time already gone."""
    import dataclasses

    from eskin.device.physics import skin_params

    sim = SimulatedBoard(dataclasses.replace(skin_params(params.sim),
                                             drift_offset_pf=REAL_DRIFT_PF),
                         skin=PAPER_SKIN, rest_length_mm=float(params.acquire.rest_length_mm),
                         frame_period_ms=int(params.sim_board.frame_period_ms))
    sim.handle(f"SIM WAIT {int(wait_s * 1000)}".encode())
    return sim


def scripted(stack, sim, settings, script, end_ms: int, batch: int = 32):
    """Live estimates of ``sim``'s stream until board time ``end_ms``; ``script`` is (board
    time, command) pairs, each sent before the first batch that reaches it."""
    script = list(script)

    def batches():
        for events in accelerated_stream(sim, batch_frames=batch):
            if events[0].frame.t_ms >= end_ms:
                return
            yield events
            while script and events[-1].frame.t_ms + sim.frame_period_ms >= script[0][0]:
                sim.handle(script.pop(0)[1].encode())

    return [r for r in live_estimates(stack, batches(), settings=settings) if "seq" in r]


@pytest.fixture(scope="module")
def onnx_full_stretch(repo_params, tmp_path_factory):
    """The small scene's stack, trained at rest and at the scene's largest stretch (16 mm)
    instead of 8 mm: the stretch where the detector is least sure (issue 57)."""
    scenes = small_scenes(repo_params)
    scenes["scenes"]["single_force"]["stretches"] = [1.0, 1.15842]
    root = tmp_path_factory.mktemp("full_stretch")
    return ExportedStack.from_file(write_stack(small_stack(scenes, root), root / "stack.onnx",
                                               sources={}))


@pytest.mark.heavy  # 28 s: fifteen minutes of board time, frame by frame
def test_a_five_minute_press_at_full_stretch_leaves_no_phantom_with_real_drift(
        params, onnx_full_stretch):
    """Issue 57's acceptance: at the largest stretch (16 mm) with real-sized drift, a
    5-minute press at a corner, then 10 untouched minutes (in board time, streamed
    faster): no contact after the release's first second. From 1,200 s of board time on
    the corner's terminals drift about 10 counts down under the press (the seed's
    drift). On main before issue 57 (baseline frozen through any contact) 0.20 % of the
    frames after the release were in contact, the first 450 s after it."""
    sim = real_drift_board(params, wait_s=1200)
    start = sim._t_ms
    press_at = start + 23_000
    release = press_at + 5 * 60_000
    records = scripted(onnx_full_stretch, sim, params.live, [
        (start + 3000, "STRETCH 16"), (press_at, "SIM PRESS 1 1 3.2536 100"),
        (release, "SIM CLEAR")], end_ms=release + 10 * 60_000)
    t = np.array([r["t_ms"] for r in records])
    contact = np.array([r["contact"] for r in records])
    assert t[-1] >= release + 10 * 60_000 - 100
    assert not contact[t < press_at].any()
    assert contact[(t >= press_at + 1000) & (t < release)].all()  # held to its end
    after = t >= release + 1000
    assert after.sum() > 49_000
    assert not contact[after].any(), (
        f"{contact[after].mean():.2%} of the frames after the release's first second are "
        f"in contact, the first at {(t[after][contact[after]][0] - release) / 1000:.1f} s")


@pytest.mark.heavy  # minutes of board time, frame by frame
def test_a_press_held_through_stretch_changes_is_held_and_placed(params, onnx):
    """Issue 57: a stretch change re-references the expected reading (from the stretch the
    channels say, on every frame) without losing a press held through it: a 3.25 N press
    held while the skin is stretched to 8 mm and back, then released: in contact all
    through, placed on its node, and untouched again within a second of the release."""
    sim = board(params)
    press_at, release = 10_000, 130_000
    records = scripted(onnx, sim, params.live, [
        (press_at, "SIM PRESS 5 5 3.2536 100"), (40_000, "STRETCH 8"),
        (100_000, "STRETCH 0"), (release, "SIM CLEAR")], end_ms=release + 30_000, batch=8)
    t = np.array([r["t_ms"] for r in records])
    contact = np.array([r["contact"] for r in records])
    held = (t >= press_at + 1000) & (t < release)
    assert not contact[t < press_at].any()
    assert contact[held].all()
    placed = [(r["x"], r["y"]) == (5, 5) for r, h in zip(records, held, strict=True) if h]
    assert np.mean(placed) >= 0.95
    assert not contact[t >= release + 1000].any()


def test_a_contact_is_frozen_whole_for_its_first_seconds_then_only_on_its_channels():
    """Issue 57: with contact_channels a contact's own channels stay frozen and the others
    are followed, but only after live.baseline.frozen_first_s (10 s) of a press: followed
    from a contact's first frame, the live hour (seed 39) had 4.2 % phantom frames at 16
    mm, none frozen whole. Here half the channels drift 3 counts during a press on x5, y5;
    a contact with no channel beyond the gate is not held."""
    from eskin.config.live import LiveBaseline
    from eskin.deploy.live import Tare, terminals_under
    from eskin.deploy.stack import RestTable

    slope = np.linspace(70, 90, 20)
    rest = RestTable(np.array([1.0, 1.08, 1.16]), 300 + np.outer([0, 1, 2], slope))
    baseline = LiveBaseline()
    tare = Tare.take(np.tile(rest.at(1.0) + 5, (10, 1)), rest, baseline=baseline)
    tared = tare.offset.copy()
    near = terminals_under({"x": 5, "y": 5}, PAPER_SKIN, 2)
    drift = np.where(np.arange(20) % 2 == 1, 3.0, 0.0)
    pressed = rest.at(1.0) + 5 + drift + np.where(near, 20.0, 0.0)
    for _ in range(int(9.9 / 0.012)):  # the first 9.9 s: nothing followed
        assert not tare.track(pressed, 12.0, under_contact=near)
    assert np.array_equal(tare.offset, tared)
    for _ in range(int(10 * baseline.time_constant_s / 0.012)):  # then 10 time constants:
        tare.track(pressed, 12.0, under_contact=near)             # all but its own
    moved = tare.offset - tared
    assert np.array_equal(moved[near], np.zeros(near.sum()))
    # the others followed their drift, up to a part common to them all (a common rise
    # reads as stretch: the two are one on a frame)
    left = moved[~near] - drift[~near]
    assert np.ptp(left) < 1.0 and np.ptp(moved[~near]) > 2.0, moved[~near]
    # a contact with no channel beyond the gate (a phantom, not a press) is not held
    tare._contact_ms, tare._pressed, after = 0.0, False, tare.offset.copy()
    assert tare.track(rest.at(1.0) + after + drift, 12.0, under_contact=near)
    assert not np.array_equal(tare.offset[~near], after[~near])
    # untouched, the expected reading goes on beyond the largest trained stretch (the
    # skin sits there); in contact it stops there (drift the contact leaves reads as it)
    beyond = rest.at(1.2) + tare.offset
    assert np.allclose(tare.expected(beyond), beyond)
    assert np.all(tare.expected(beyond, ignore=near) < beyond - 10)


def _corner_pair_tare():
    """A tare on a 10 x 10 skin's made-up untouched table (three stretches), followed as
    params.yaml says, and the channels of a light pair at (1, 1) and (10, 10): 12 counts
    on its lines, 7 and 2 on their flanks (the harder hour's 1.29 N pair, by the log)."""
    from eskin.config.live import LiveBaseline
    from eskin.deploy.live import Tare, terminals_under
    from eskin.deploy.stack import RestTable

    rest = RestTable(np.array([1.0, 1.08, 1.16]),
                     300 + np.outer([0, 1, 2], np.linspace(70, 90, 20)))
    tare = Tare.take(np.tile(rest.at(1.0) + 5, (10, 1)), rest, baseline=LiveBaseline())
    first = terminals_under({"x": 1, "y": 1}, PAPER_SKIN, 2)
    both = first | terminals_under({"x": 10, "y": 10}, PAPER_SKIN, 2)
    line = np.r_[np.arange(1, 11), np.arange(1, 11)]
    rise = np.select([np.isin(line, [1, 10]), np.isin(line, [2, 9]), np.isin(line, [3, 8])],
                     [12.0, 7.0, 2.0], 0.0)
    return tare, rest.at(1.0) + 5, rise, first, both


def test_a_count_that_flickers_frees_none_of_a_pairs_channels():
    """Issue 57: the harder hour's 10-minute light pair was lost after about 450 s. On the
    frames the stack counted one contact, the other's channels were no contact's: its
    flanks (within the gate) were followed into the press, and the first contact's summed
    rise, half the pair's peak, passed for a lifted press once the drift bound grew past
    its lines' 12 counts. Here 12 minutes, one frame in 20 counted one contact: the
    pair's channels stay frozen (on main before, they took in 11 of their lines' 12
    counts and 6 of their flanks' 7: the pair was gone)."""
    tare, untouched, rise, first, both = _corner_pair_tare()
    tared = tare.offset.copy()
    noise = np.random.default_rng(57).normal(0.0, 1.0, (6_000, 20))
    for i in range(6_000):  # 120 ms apart: the tracking is in board time
        tare.track(untouched + rise + noise[i], 120.0,
                   under_contact=first if i % 20 == 19 else both)
    moved = np.abs(tare.offset - tared)
    assert moved[both].max() < 0.5, moved.round(1)


def test_what_a_lifted_press_left_is_followed_within_a_second():
    """Issue 57: after the harder hour's 10-minute pair lifted, what the freeze had missed
    (drift under the press, a few counts on some of its channels) read as a contact at
    (10, 1) for 4.3 s while the offset followed it at the baseline's 20 s. Judged lifted
    on the contact's rise averaged over lift_average_s, what is left is followed at
    lifted_time_constant_s (0.5 s): within a second, under a count."""
    tare, untouched, rise, first, both = _corner_pair_tare()
    for _ in range(int(600 / 0.12)):  # ten minutes held (a frame each 120 ms: board time)
        tare.track(untouched + rise, 120.0, under_contact=both)
    left = np.where(np.isin(np.arange(20), [9, 10]), 4.0, 0.0)  # x10 and y1: 4 counts
    for _ in range(int(1.0 / 0.012)):
        tare.track(untouched + left, 12.0, under_contact=both)
    after = untouched + left - tare.expected(untouched + left, ignore=both)
    assert np.abs(after).max() < 1.0, after.round(1)
