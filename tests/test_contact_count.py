"""Two contacts that can be zero, one or two (issue 57, item 3): a two-contact scene
recorded with ``contact_counts: [0, 1, 2]`` learns how many contacts press, and its stack,
live on the simulated board, says 0 for an untouched skin, 1 for one weight and 2 for two,
placing only those it counts. The board is the Python simulator over a pty; the models
are the repo's defaults for the kind, trained on a small scene."""

from __future__ import annotations

import contextlib
import copy

import joblib
import numpy as np
import pandas as pd
import pytest

from eskin.acquisition.session import simulated_board
from eskin.config.base import validate_params
from eskin.config.params import Params
from eskin.data.plan import two_force_plan
from eskin.data.schema import contact_count, read_dataset, read_metadata
from eskin.deploy.live import live_estimates, stream_events
from eskin.deploy.stack import SkinStack, rest_readings
from eskin.device.link import SerialLink
from eskin.device.physics import skin_params
from eskin.evaluation.crossval import fit_final
from eskin.evaluation.pairs import score_pairs
from eskin.evaluation.tasks import get_task
from eskin.learning.choice import model_settings
from eskin.learning.estimators import build_model
from eskin.skin import PAPER_SKIN
from tests.conftest import featurize_step, prepared_scene, small_scenes, typed

COUNTS = [0, 1, 2]


def counting_params(repo_params: dict) -> dict:
    params = small_scenes(repo_params)
    params["scenes"]["two_force"]["contact_counts"] = COUNTS
    return params


def test_a_plan_with_fewer_contacts_adds_them_after_the_papers_pairs():
    paper = two_force_plan("p", [1.0], [1.0, 5.0], [1, 6], [1, 6], samples=2)
    counted = two_force_plan("p", [1.0], [1.0, 5.0], [1, 6], [1, 6], samples=2,
                             contact_counts=COUNTS)
    # the pairs' trials are the paper's plan's, in its order: its rows keep their bytes
    assert counted.conditions[:len(paper.conditions)] == paper.conditions
    added = counted.conditions[len(paper.conditions):]
    touching = [sum(c.touches for c in condition.contacts) for condition in added]
    assert touching == [1] * 8 + [0] * 2  # 4 nodes × 2 forces alone, then 2 untouched
    assert all(not condition.contacts[1].touches for condition in added)  # absent: last
    assert len({c.key("d", "f") for c in counted.conditions}) == len(counted.conditions)


@pytest.mark.parametrize(("counts", "says"), [
    ([0, 1], "2 included"), ([1, 2, 3], "from 0 to 2"), ([2, 2], "each count once")])
def test_contact_counts_the_kind_cannot_have_are_refused_in_one_line(repo_params, counts,
                                                                    says):
    params = copy.deepcopy(repo_params)
    params["scenes"]["two_force"]["contact_counts"] = counts
    with pytest.raises(Exception, match=says):
        validate_params(params, Params)
    params = copy.deepcopy(repo_params)
    params["scenes"]["single_force"]["contact_counts"] = COUNTS
    with pytest.raises(Exception, match="scenes of several contacts"):
        validate_params(params, Params)


def test_the_papers_pairs_only_plan_has_nothing_to_count_and_says_so():
    frame = pd.DataFrame({"force1": [1.0, 2.0], "x1": [1, 1], "y1": [1, 1],
                          "force2": [1.0, 3.0], "x2": [6, 6], "y2": [6, 6], "stretch": 1.0})
    reason = get_task("two_force", "detect").unsupported(frame)
    assert "every sample of this scene has 2" in reason and "contact_counts" in reason
    frame.loc[1, ["x2", "y2", "force2"]] = 0
    assert get_task("two_force", "detect").unsupported(frame) is None
    assert contact_count(frame).tolist() == [2, 1]


def test_pairs_are_scored_on_the_samples_where_both_contacts_press():
    rows = [{"scheme": "conditions", "trial": f"t{i}", "sample": 0, "fold": 0,
             "x1_true": 1, "y1_true": 1, "x2_true": 6 if i else 0, "y2_true": 6 if i else 0,
             "x1_pred": 1, "y1_pred": 1, "x2_pred": 6 if i else 1, "y2_pred": 6 if i else 1}
            for i in range(3)]
    scores = score_pairs(pd.DataFrame(rows), None)["conditions"]
    # the one-contact sample (t0) is no pair: the two pairs are right
    assert scores["pair_accuracy"] == pytest.approx(1.0)


@pytest.fixture(scope="module")
def counting_stack(tmp_path_factory, repo_params):
    params = counting_params(repo_params)
    root = tmp_path_factory.mktemp("counting")
    processed = prepared_scene(params, "two_force", root)
    featurize_step(params, "two_force", root / "processed", root / "features",
                   root / "models")
    features = read_dataset(root / "features" / "two_force.parquet")
    models = {}
    for name in ("detect", "localise", "force"):
        task = get_task("two_force", name)
        model, hyper = model_settings(getattr(typed(params).train, name), "tuned", "two_force")
        models[name] = fit_final(task, features, build_model(task.role, model, hyper,
                                                             PAPER_SKIN), PAPER_SKIN)
    featurizer = joblib.load(root / "models" / "two_force" / "featurizer.joblib")
    stack = SkinStack("two_force", "two_force", PAPER_SKIN, featurizer, models,
                      device=read_metadata(processed)["device"],
                      rest=rest_readings(pd.read_parquet(processed), PAPER_SKIN))
    return params, stack, features


# The commands, each sent once its phase before has JUDGED estimates; a phase is judged on
# the JUDGED frames that follow the first SETTLE after its command's #OK, found by board seq
# (estimates lag the board under load: counting them instead judged frames from before a
# press, a CI run of 9c4860f). SETTLE is a second of frames (8 ms each). The light weight
# (1.29 N) checks the baseline: followed at a time constant of 0.5 s, it took in the
# weight's flank channels within that second (drift 0.5 → 8.5 counts) and live lost the
# press (bdb6d66); at 20 s it holds them (issue 57). Its count is not judged: this small
# scene's detector sees it on about half the frames (p ≥ 0.8 on 39 %, at most 4 frames
# running), a known miss of the detector, not of the baseline. The one-weight phase is
# the issue's own 3.25 N at (6, 6); the two-weight phase adds 5.21 N at (1, 1) to the
# light weight.
SCRIPT = ["SIM PRESS 6 6 3.2536", "SIM CLEAR", "SIM PRESS 6 6 1.2936", "SIM PRESS 1 1 5.2136",
          "SIM CLEAR"]
SETTLE, JUDGED = 125, 40


@pytest.mark.heavy
@pytest.mark.alone
def test_live_counts_none_one_and_two_contacts_on_the_simulated_board(counting_stack):
    params, stack, features = counting_stack
    assert np.bincount(contact_count(features)).tolist() == [10, 90, 720]
    assert stack.columns[1:4] == ["contact", "contact_probability", "contacts"]
    settings = typed(params)
    records, begins = [], []  # each phase begins after this seq
    with contextlib.ExitStack() as resources:
        board = resources.enter_context(simulated_board(
            skin_params(settings.sim), rest_length_mm=float(settings.acquire.rest_length_mm),
            frame_period_ms=8))
        link = resources.enter_context(SerialLink(board.port, timeout_s=5.0))
        link.connect()
        stream = resources.enter_context(contextlib.closing(stream_events(link)))
        script = list(SCRIPT)
        for record in live_estimates(stack, stream, tare_frames=50, settings=settings.live):
            if "seq" not in record:
                continue
            records.append(record)
            if not begins:
                begins.append(record["seq"] - 1)
            if sum(r["seq"] > begins[-1] + SETTLE for r in records) < JUDGED:
                continue
            if not script:
                break
            link.command(script.pop(0))
            # every frame parsed so far came before the #OK or with it: later ones after
            begins.append(max(link.protocol.last_accepted.seq, records[-1]["seq"]))
    live = pd.DataFrame(records)
    untouched, one, cleared, light, two, released = phases = [
        live[live["seq"] > begin + SETTLE].head(JUDGED) for begin in begins]
    assert all(len(phase) == JUDGED for phase in phases)
    for phase in (untouched, cleared, released):
        assert (phase["contacts"] == 0).all() and phase["x1"].isna().all()
    # a second and more into the light press, its channels are not followed in
    assert light["drift_counts"].max() <= 1.0, light["drift_counts"].describe()
    assert (one["contacts"] == 1).mean() >= 0.75, one["contacts"].value_counts()
    single = one[one["contacts"] == 1]
    assert ((single["x1"] == 6) & (single["y1"] == 6)).mean() >= 0.9
    assert single["x2"].isna().all() and (single["force2"] == 0).all()
    assert (two["contacts"] == 2).mean() >= 0.9, two["contacts"].value_counts()
    # the pressed rows and columns: the pair or its ghost, which only the amplitudes tell
    # apart (how often they do is the batch pairs' score, over every pair of the plan).
    # This one pair's 40 frames: 34 of 40 in the CI of e0de6b7, 36 or more in 8 runs here;
    # a frame is wrong where one contact takes a node of the other's row and column
    pairs = two[two["contacts"] == 2]
    lit = [{r.x1, r.x2} == {r.y1, r.y2} == {1.0, 6.0} for r in pairs.itertuples()]
    assert np.mean(lit) >= 0.8, pairs[["x1", "y1", "x2", "y2"]].value_counts()
