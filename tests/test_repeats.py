"""Repetitions (issue 41): a plan recorded ``repeats`` times, each repetition a new trial of
the same skin, and the CV schemes named for what they hold out: ``conditions`` whole
conditions, ``trials`` new trials of conditions that training has seen."""

import os
import signal

import numpy as np
import pandas as pd
import pytest
from conftest import acquire_step, acquire_until, ingest_step, resume_and_ingest, small_scenes

from eskin.data.rawlog import read_log
from eskin.data.schema import LABELS, read_metadata
from eskin.evaluation.folds import applicable_schemes, assign_folds
from eskin.skin import PAPER_SKIN
from eskin.steps.folds import folds_at

CHANNELS = PAPER_SKIN.channels
CONTENT = ["trial", "sample", *CHANNELS, *LABELS["single_force"]]
CONDITION = LABELS["single_force"]
TRIALS = 202  # one stretch × two forces × 101 nodes (node 0: no contact)


def repeated(repo_params, repeats: int) -> dict:
    params = small_scenes(repo_params)
    params["scenes"]["single_force"].update(stretches=[1.0], samples=3, repeats=repeats)
    return params


@pytest.fixture(scope="module")
def recorded(tmp_path_factory, repo_params):
    """The small scene once, then the same log grown to ``repeats: 2``."""
    root = tmp_path_factory.mktemp("repeats")
    raw = root / "raw" / "single_force"
    summaries, frames = [], []
    for repeats in (1, 2):
        params = repeated(repo_params, repeats)
        summaries.append(acquire_step(params, "single_force", raw, progress=False).summary)
        out = root / f"repeats_{repeats}"
        ingest_step(params, "single_force", raw, out)
        frames.append(pd.read_parquet(out / "single_force.parquet"))
    return root, summaries, frames


def test_repeats_record_the_whole_plan_again_as_new_trials(recorded):
    root, (once_summary, twice_summary), (once, twice) = recorded
    assert f"{TRIALS} trial(s) acquired, 0 reused of {TRIALS}" in once_summary
    # Growing the plan to two repetitions records only the second.
    assert f"{TRIALS} trial(s) acquired, {TRIALS} reused of {2 * TRIALS}" in twice_summary
    assert len(twice) == 2 * TRIALS * 3
    first = twice.iloc[:len(once)].reset_index(drop=True)
    pd.testing.assert_frame_equal(first[CONTENT], once[CONTENT])  # the first is the plan's
    assert twice.groupby(CONDITION)["trial"].nunique().eq(2).all()
    assert twice["trial"].nunique() == 2 * TRIALS
    assert read_metadata(root / "repeats_2" / "single_force.parquet")["plan"]["repeats"] == 2
    # A new trial of the same skin: every reading differs (noise, the drift's offset, the
    # indenter's seating), the press's signal does not.
    second = twice.iloc[len(once):].reset_index(drop=True)
    assert (first[CHANNELS].to_numpy() != second[CHANNELS].to_numpy()).mean() > 0.5
    pressed = first["x"] > 0
    rise_1 = first[CHANNELS][pressed].to_numpy() - first[CHANNELS][~pressed].mean().to_numpy()
    rise_2 = second[CHANNELS][pressed].to_numpy() - second[CHANNELS][~pressed].mean().to_numpy()
    assert np.corrcoef(rise_1.ravel(), rise_2.ravel())[0, 1] > 0.9


@pytest.mark.heavy
def test_repeats_resume_after_a_kill_and_give_the_uninterrupted_dataset(recorded, tmp_path,
                                                                        repo_params):
    _, _, (_, twice) = recorded
    process, log = acquire_until(repeated(repo_params, 2), tmp_path, complete=TRIALS + 40)
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    before = len(read_log(log).completed)
    assert TRIALS < before < 2 * TRIALS, "killed in the second repetition"

    frame = resume_and_ingest(tmp_path, 2 * TRIALS, before)
    pd.testing.assert_frame_equal(frame[CONTENT], twice[CONTENT])


def test_the_trials_scheme_tests_trials_of_conditions_seen_in_training(recorded):
    _, _, (_, twice) = recorded
    folds = assign_folds(twice, "single_force", "trials", 10, 42, skin=PAPER_SKIN)
    assert set(folds) == set(range(10))
    condition = twice[CONDITION].astype(str).agg("/".join, axis=1).to_numpy()
    trial = twice["trial"].to_numpy()
    for fold in range(10):
        test, train = folds == fold, folds != fold
        assert not set(trial[test]) & set(trial[train]), "a trial on both sides"
        assert set(condition[test]) <= set(condition[train]), "a test condition never trained"
    # The same draw from the same seed.
    again = assign_folds(twice, "single_force", "trials", 10, 42, skin=PAPER_SKIN)
    assert np.array_equal(folds, again)


def test_the_conditions_scheme_holds_out_whole_conditions_every_trial_of_them(recorded):
    _, _, (once, twice) = recorded
    folds = assign_folds(twice, "single_force", "conditions", 10, 42, skin=PAPER_SKIN)
    per_condition = pd.Series(folds).groupby(
        [twice[c].to_numpy() for c in CONDITION]).nunique()
    assert per_condition.eq(1).all(), "a condition's trials on both sides"
    # With one trial per condition, conditions are trials: conditions CV as before repeats.
    from sklearn.model_selection import StratifiedGroupKFold

    from eskin.evaluation.folds import strata
    by_trial = np.full(len(once), -1)
    splits = StratifiedGroupKFold(5, shuffle=True, random_state=42).split(
        np.zeros(len(once)), strata(once, "single_force", PAPER_SKIN), once["trial"])
    for k, (_, test) in enumerate(splits):
        by_trial[test] = k
    assert np.array_equal(assign_folds(once, "single_force", "conditions", 5, 42,
                                       skin=PAPER_SKIN), by_trial)


def test_a_scene_recorded_once_is_not_scored_under_trials_and_says_why(recorded, tmp_path):
    root, _, (once, twice) = recorded
    assert applicable_schemes(once, "single_force", ["stratified", "conditions", "trials"]) == [
        "stratified", "conditions"]
    assert applicable_schemes(twice, "single_force", ["trials"]) == ["trials"]
    with pytest.raises(ValueError, match=r"202 of 202 conditions have one trial; record each "
                                         r"at least twice \(scenes.<scene>.repeats: 2\)"):
        assign_folds(once, "single_force", "trials", 10, 42, skin=PAPER_SKIN)
    said = folds_at(root / "repeats_1" / "single_force.parquet",
                    tmp_path / "once.parquet", schemes=["stratified", "trials"],
                    n_splits=5, seed=42, scene="single_force")
    assert "for stratified CV; not trials: a condition has only one trial" in said
    assert list(pd.read_parquet(tmp_path / "once.parquet").columns) == ["trial", "stratified"]
    said = folds_at(root / "repeats_2" / "single_force.parquet",
                    tmp_path / "twice.parquet", schemes=["conditions", "trials"],
                    n_splits=10, seed=42, scene="single_force")
    assert said.endswith("for conditions, trials CV")


def test_a_recording_whose_trials_span_conditions_holds_out_whole_trials(recorded):
    """An import read by file or by time: labels change within a trial and recur across
    trials, so no trial is one condition; conditions CV holds its trials out whole."""
    from sklearn.model_selection import StratifiedGroupKFold

    from eskin.evaluation.folds import strata

    _, _, (once, _) = recorded
    spans = once.assign(trial=[f"file{k // 60:02d}" for k in range(len(once))])
    folds = assign_folds(spans, "single_force", "conditions", 5, 42, skin=PAPER_SKIN)
    assert pd.Series(folds).groupby(spans["trial"].to_numpy()).nunique().eq(1).all()
    by_trial = np.full(len(spans), -1)
    splits = StratifiedGroupKFold(5, shuffle=True, random_state=42).split(
        np.zeros(len(spans)), strata(spans, "single_force", PAPER_SKIN), spans["trial"])
    for k, (_, test) in enumerate(splits):
        by_trial[test] = k
    assert np.array_equal(folds, by_trial)
