"""Learning curves and the planner (issue 41): error against trials per condition on new
trials of the same simulated skin, beside the Bayes bound; `eskin plan`'s answers."""

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from conftest import acquire_step, eskin, ingest_step, small_scenes, typed, write_params

from eskin.evaluation.crossval import cross_validate
from eskin.evaluation.folds import assign_folds
from eskin.evaluation.tasks import get_task
from eskin.learning.estimators import build_model
from eskin.skin import PAPER_SKIN
from eskin.tracking import planning
from harness import benchmark, learning_curve

ROOT = Path(__file__).resolve().parents[1]
COSTS = SimpleNamespace(placement_s=30.0, frames_per_s=56.8)
SCENE = "single_force"


def small(repo_params) -> dict:
    params = small_scenes(repo_params)
    # A light force too: with 0 and 3.25 N only, the bound knows every force (R² 1.0).
    params["scenes"][SCENE].update(stretches=[1.0], forces=[0.0, 1.2936, 3.2536], samples=3)
    params["cv"]["folds"] = 3  # the gap check's conditions CV: 3 trials a node
    return params


@pytest.fixture(scope="module")
def project(tmp_path_factory, repo_params):
    """A scratch project with the small scene acquired and ingested, as the pipeline
    leaves it (data/raw, data/processed), and its Bayes bound (the bench's)."""
    root = tmp_path_factory.mktemp("curve")
    params = small(repo_params)
    write_params(root, params)
    acquire_step(params, SCENE, root / "data" / "raw" / SCENE, progress=False)
    ingest_step(params, SCENE, root / "data" / "raw" / SCENE, root / "data" / "processed")
    bound = root / "bench" / "bound" / f"{SCENE}.parquet"
    typed_params = typed(params)
    benchmark.bayes_bound(SCENE, typed_params.scenes[SCENE],
                          root / "data" / "processed" / f"{SCENE}.parquet", bound,
                          sim=typed_params.sim, seed=0, log=lambda _: None)
    return root, params, bound


@pytest.fixture(scope="module")
def curves(project):
    root, params, bound = project
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(root)
        return learning_curve.learning_curve(SCENE, typed(params), [1, 2, 4], bound_path=bound,
                                             tasks=("force", "detect", "stretch"),
                                             gap_share=0.5, gap_tasks=("force",),
                                             log=lambda _: None)


@pytest.mark.heavy
def test_the_curve_holds_out_the_datasets_own_trials_and_trains_on_new_ones(project, curves):
    root, _, _ = project
    dataset = pd.read_parquet(root / "data" / "processed" / f"{SCENE}.parquet")
    assert curves["held_out_rows"] == len(dataset) == 303 * 3
    assert curves["trials"] == "new trials of the simulated skin"
    assert curves["conditions"] == 303 and curves["placed_conditions"] == 200
    force = curves["tasks"]["force"]
    assert [p["repeats"] for p in force["points"]] == [1, 2, 4]
    assert [p["train_rows"] for p in force["points"]] == [909, 1818, 3636]
    assert force["fit"] is not None and 0.0 <= force["fit"]["floor"] <= 1.0
    # The scratch recording was the scene's own log, copied: the pipeline's is untouched.
    log = (root / "data" / "raw" / SCENE / "acquisition.log").read_text()
    assert '"repeat"' not in log
    assert "skipped" in curves["tasks"]["stretch"]  # one stretch level: nothing to learn


def test_no_point_of_the_curve_beats_the_bayes_bound(curves):
    for name in ("force", "detect"):
        entry = curves["tasks"][name]
        bound = entry["bound"]["headline"]
        best = max(p["headline"] for p in entry["points"])
        assert best <= bound + 0.002, (name, best, bound)  # 0.002: one held-out set's noise


def test_the_gap_check_scores_the_recommended_scene_under_trials_cv(curves):
    check = curves["gap_check"]["tasks"]["force"]
    r = check["recommended_repeats"]
    assert r == planning.repeats_for(curves["tasks"]["force"]["fit"], 1 - check["target"],
                                    curves["tasks"]["force"]["points"])
    # the target: half the way from the paper's model to the bound
    assert check["target"] == pytest.approx(
        check["paper_conditions"] + 0.5 * (check["bound"] - check["paper_conditions"]))
    assert check["scene_repeats"] == r + 1 and check["rows"] == 303 * 3 * (r + 1)
    model = check["scores"]["pipeline"]["first_trials"]
    assert check["gap_closed"] == pytest.approx(
        (model - check["paper_conditions"]) / (check["bound"] - check["paper_conditions"]))
    assert model <= check["bound"] + 0.01


def test_scores_on_a_subset_of_rows_are_the_cv_scores_on_every_row(project):
    root, params, _ = project
    frame = pd.read_parquet(root / "data" / "processed" / f"{SCENE}.parquet")
    task = get_task("single_force", "force")
    folds = assign_folds(frame, "single_force", "stratified", 3, 0, skin=PAPER_SKIN)
    result = cross_validate(task, frame, folds, build_model(task.role, "hist_gradient_boosting",
                                                           {"max_iter": 20}), "stratified",
                            PAPER_SKIN)
    every = np.ones(len(frame), dtype=bool)
    assert learning_curve._scored_on(task, frame, result, folds, every) == pytest.approx(
        task.headline(result.summary))
    # on part of the rows, the scores of those rows alone
    part = frame["trial"].rank(method="dense").to_numpy() % 2 == 0
    assert learning_curve._scored_on(task, frame, result, folds, part) != pytest.approx(
        task.headline(result.summary))


def test_the_planner_says_impossible_where_the_bound_forbids_it(curves):
    bound = curves["tasks"]["force"]["bound"]["headline"]
    assert bound < 0.99
    answer = planning.plan(curves, "force_r2", bound + 0.005, COSTS)
    assert answer["verdict"] == "impossible"
    assert planning.describe(answer, COSTS).endswith(
        f"impossible, the bound is {bound:.4f}: no model of these readings scores more.")


def synthetic(floor=0.04, a=0.02, b=0.8, bound=0.975) -> dict:
    """A curve document as the bench writes one, with a known curve."""
    points = [{"repeats": r, "headline": 1 - (floor + a * r ** -b), "train_rows": 0,
               "seconds": 0.0} for r in (1, 2, 3, 5, 10)]
    fit = planning.fit_curve([p["repeats"] for p in points], [1 - p["headline"] for p in points])
    return {"scene": "s", "conditions": 1212, "placed_conditions": 1200, "samples": 20,
            "tasks": {"force": {"model": "m", "metric": "r2", "points": points, "fit": fit,
                                "floor_score": 1 - fit["floor"],
                                "bound": {"headline": bound}}}}


def test_the_fit_recovers_a_known_curve_and_the_planner_reads_it():
    document = synthetic()
    fit = document["tasks"]["force"]["fit"]
    assert fit["floor"] == pytest.approx(0.04, abs=1e-4)
    assert fit["b"] == pytest.approx(0.8, abs=1e-3)
    answer = planning.plan(document, "force_r2", 0.948, COSTS)
    # 1 − (0.04 + 0.02 r^−0.8) ≥ 0.948 ⇔ r^−0.8 ≤ 0.6 ⇔ r ≥ 1.89: two trials per condition
    assert answer["verdict"] == "possible" and answer["repeats"] == 2
    assert answer["trials"] == 2 * 1212 and answer["frames"] == 2 * 1212 * 20
    assert answer["placements"] == 2 * 1200
    assert answer["sampling_s"] == pytest.approx(2 * 1212 * 20 / 56.8)
    assert answer["bench_h"] == pytest.approx((2 * 1212 * 20 / 56.8 + 2400 * 30) / 3600)
    assert not answer["extrapolated"]
    far = planning.plan(document, "force_r2", 0.9595, COSTS)
    assert far["extrapolated"] and far["repeats"] > 10
    near = planning.plan(document, "force_r2", 0.95999, COSTS)  # r ≈ 13,000 by the curve
    assert near["verdict"] == "out of reach" and "more than 1000 trials" in near["why"]
    floor = planning.plan(document, "force_r2", 0.965, COSTS)
    assert floor["verdict"] == "beyond the floor"
    assert "levels off at 0.9600 (the bound is 0.9750" in floor["why"]
    with pytest.raises(ValueError, match="unknown target 'force_mae' for scene s; one of: "
                                         "force_r2"):
        planning.plan(document, "force_mae", 0.3, COSTS)


def test_a_measured_point_that_misses_the_target_outranks_the_fit():
    """The fit says two trials; the point measured at two fell short: the plan is the next
    count the fit says reaches the target past it (two-contact force, issue 41)."""
    document = synthetic()
    force = document["tasks"]["force"]
    assert planning.plan(document, "force_r2", 0.948, COSTS)["repeats"] == 2
    force["points"][1]["headline"] = 0.947  # measured at 2: short of 0.948
    answer = planning.plan(document, "force_r2", 0.948, COSTS)
    assert answer["verdict"] == "possible" and answer["repeats"] == 3
    force["points"][2]["headline"] = 0.947  # and at 3: past it, the fit's next count
    assert planning.plan(document, "force_r2", 0.948, COSTS)["repeats"] == 4


def test_eskin_plan_answers_from_the_benchs_curves_and_refuses_bad_targets(project, curves):
    root, _, _ = project
    out = root / "reports" / "learning_curve"
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{SCENE}.json").write_text(json.dumps(curves))
    bench = root / "bench"
    (bench / "params.yaml").write_text(
        (ROOT / "bench" / "params.yaml").read_text())
    bound = curves["tasks"]["force"]["bound"]["headline"]
    said = eskin(["plan", SCENE, "--target", f"force_r2={bound + 0.005}"], root)
    assert said.returncode == 0, said.stderr
    assert f"impossible, the bound is {bound:.4f}" in said.stdout
    first = curves["tasks"]["force"]["points"][0]["headline"]
    said = eskin(["plan", SCENE, "--target", f"force_r2={first - 0.01:.4f}"], root)
    assert said.returncode == 0, said.stderr
    assert "repeats: 1 — 1 trial(s) per condition; 303 trials, 909 frames" in said.stdout
    bad = eskin(["plan", SCENE, "--target", "force_r2"], root)
    assert bad.returncode == 1
    assert bad.stderr.strip().splitlines()[-1].endswith(
        "--target 'force_r2': give it as <task>_<metric>=<value>, e.g. force_r2=0.95")
    missing = eskin(["plan", "two_force", "--target", "force_r2=0.9"], root)
    assert missing.returncode == 1
    assert "no learning curves for scene two_force; run `cd bench && dvc repro " \
           "learning_curve@two_force` (make bench)" in missing.stderr


def test_a_recorded_scene_of_two_trials_a_condition_is_subsampled_not_recorded(tmp_path,
                                                                              repo_params):
    """An import (another lab's files) whose conditions were each recorded twice: its own
    trials make the curve (one held out, one trained on); nothing is acquired."""
    twice = small(repo_params)
    twice["scenes"][SCENE]["repeats"] = 2
    raw = tmp_path / "raw"
    acquire_step(twice, SCENE, raw, progress=False)
    ingest_step(twice, SCENE, raw, tmp_path / "processed")
    frame = pd.read_parquet(tmp_path / "processed" / f"{SCENE}.parquet")
    csv = tmp_path / "lab.csv"
    frame[[*PAPER_SKIN.channels, "force", "x", "y", "stretch"]].to_csv(csv, index=False,
                                                                       header=False)
    lab = small(repo_params)
    lab["scenes"] = {"lab": {"kind": "single_force", "source": "import",
                             "import": {"path": str(csv)}}}
    write_params(tmp_path, lab)
    acquire_step(lab, "lab", tmp_path / "data" / "raw" / "lab", progress=False)
    ingest_step(lab, "lab", tmp_path / "data" / "raw" / "lab", tmp_path / "data" / "processed")
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(tmp_path)
        document = learning_curve.learning_curve("lab", typed(lab), [1, 2], bound_path=None,
                                                 tasks=("force",), log=lambda _: None)
    assert document["trials"] == "the scene's own"
    assert document["repeats"] == [1]  # two trials a condition: one to hold out, one to train
    force = document["tasks"]["force"]
    assert force["fit"] is None and "bound" not in force
    assert np.isfinite(force["points"][0]["headline"])

