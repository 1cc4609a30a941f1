"""Single- and two-force learning: folds, tasks, models, metrics, determinism."""

import contextlib
import json

import numpy as np
import pandas as pd
import pytest
from conftest import featurize_step, prepared_scene, small_scenes, train_step
from sklearn.utils.estimator_checks import check_estimator

from eskin.catalog import TASK_NAMES
from eskin.config.train import TaskModels
from eskin.data.schema import md5_file
from eskin.evaluation.crossval import cross_validate, parallel_backend
from eskin.evaluation.folds import assign_folds, strata
from eskin.evaluation.tasks import TASKS, get_task
from eskin.learning.choice import model_settings
from eskin.learning.estimators import (
    REGISTRY,
    SubsampledGaussianProcess,
    build_model,
)
from eskin.learning.features import BaselineDelta, fit_featurizer
from eskin.skin import PAPER_SKIN

CHANNELS = PAPER_SKIN.channels


@pytest.fixture(scope="module")
def project(tmp_path_factory, repo_params):
    """Small scenes acquired over the pty, ingested and featurized, in a scratch project."""
    params = small_scenes(repo_params)
    params["cv"]["folds"] = 5  # training tests; the fold tests ask for 10 themselves
    params["train"]["localise"]["paper"]["n_estimators"] = 20
    params["train"]["force"]["paper"]["subsample"] = 300
    root = tmp_path_factory.mktemp("project")
    for scene in ("single_force", "two_force"):
        prepared_scene(params, scene, root)
        featurize_step(params, scene, root / "processed", root / "features", root / "models")
    return params, root


def features(project, scene="single_force"):
    return pd.read_parquet(project[1] / "features" / f"{scene}.parquet")


def train(project, scene, task, out, params=None, **kwargs):
    return train_step(params or project[0], scene, task, project[1] / "features",
                      scores_path=out / "scores.json",
                      predictions_path=out / "oof.parquet",
                      model_path=out / "model.joblib",
                      **kwargs).summary


# ------------------------------------------------------------------ folds

def test_every_stratified_fold_holds_every_node(project):
    frame = features(project)
    folds = assign_folds(frame, "single_force", "stratified", 10, seed=42, skin=PAPER_SKIN)
    nodes = strata(frame, "single_force", PAPER_SKIN)
    assert set(folds) == set(range(10))
    for fold in range(10):
        assert set(nodes[folds == fold]) == set(range(101)), f"fold {fold} misses a node"


def test_conditions_folds_never_put_a_trial_on_both_sides(project):
    frame = features(project)
    folds = assign_folds(frame, "single_force", "conditions", 10, seed=42, skin=PAPER_SKIN)
    folds_per_trial = pd.Series(folds).groupby(frame["trial"].to_numpy()).nunique()
    assert folds_per_trial.eq(1).all()
    assert set(folds) == set(range(10))


def test_stratified_folds_split_trials_which_is_why_conditions_exists(project):
    frame = features(project)
    folds = assign_folds(frame, "single_force", "stratified", 10, seed=42, skin=PAPER_SKIN)
    assert pd.Series(folds).groupby(frame["trial"].to_numpy()).nunique().gt(1).any()


def test_folds_follow_the_seed(project):
    frame = features(project)
    a = assign_folds(frame, "single_force", "stratified", 10, seed=1, skin=PAPER_SKIN)
    again, other = (assign_folds(frame, "single_force", "stratified", 10, seed=seed,
                                 skin=PAPER_SKIN) for seed in (1, 2))
    assert np.array_equal(a, again)
    assert not np.array_equal(a, other)


def test_two_force_strata_are_the_pair_of_nodes(project):
    frame = features(project, "two_force")
    pairs = strata(frame, "two_force", PAPER_SKIN)
    # the 36 pairs of 9 nodes; the default scene counts (contact_counts: [0, 1, 2]), so
    # also each node alone and the untouched skin
    assert len(np.unique(pairs)) == 36 + 9 + 1
    folds = assign_folds(frame, "two_force", "stratified", 10, seed=0, skin=PAPER_SKIN)
    assert set(pairs[folds == 0]) == set(np.unique(pairs))


def test_conditions_cv_with_too_few_conditions_is_a_clear_error(project):
    frame = features(project).iloc[:15]  # three trials
    with pytest.raises(ValueError, match="needs at least 10 conditions; this dataset has 3"):
        assign_folds(frame, "single_force", "conditions", 10, seed=0, skin=PAPER_SKIN)


# ------------------------------------------------------------------ tasks and labels

def test_localise_uses_contact_samples_only_and_force_is_physical(project):
    frame = features(project)
    localise = get_task("single_force", "localise")
    rows = localise.rows(frame)
    assert (frame.loc[rows, "x"] > 0).all() and (frame.loc[rows, "force"] > 0).all()
    force = get_task("single_force", "force").target_values(frame)["force"]
    node_zero = frame["x"].to_numpy() == 0
    assert (frame.loc[node_zero, "force"] > 0).any()  # recorded at every force level...
    assert (force[node_zero] == 0).all()               # ...but no weight was on the skin


def test_a_single_stretch_level_skips_stretch_with_its_reason(project, tmp_path):
    from eskin.reporting.report import headline_metrics

    params, root = project
    frame = features(project)
    one_level = root / "one_level"
    one_level.mkdir(exist_ok=True)
    from eskin.data.schema import read_metadata, write_dataset
    meta = read_metadata(root / "features" / "single_force.parquet")
    write_dataset(frame[frame["stretch"] == 1.0], "single_force",
                  one_level / "single_force.parquet", meta)
    result = train_step(params, "single_force", "stretch", one_level,
                        folds_path=tmp_path / "folds.parquet", scores_path=tmp_path / "s.json",
                        predictions_path=tmp_path / "p.parquet",
                        model_path=tmp_path / "model.joblib")
    assert "skipped" in result.summary
    assert result.status == "skipped" and "two or more stretch levels" in result.reason
    scores = json.loads((tmp_path / "s.json").read_text())
    assert scores["status"] == "skipped"
    assert "two or more stretch levels" in scores["reason"]
    # no headline: the report's metrics leave a skipped task out
    assert headline_metrics({"single_force": {"stretch": scores}}) == {}


def test_every_kind_has_the_catalogs_tasks_each_with_a_registered_role():
    for kind in ("single_force", "two_force"):
        assert tuple(TASKS[kind]) == TASK_NAMES
    assert set(TASKS["two_force"]["force"].targets) == {"force1", "force2"}
    for tasks in TASKS.values():
        for task in tasks.values():
            assert "paper" in REGISTRY[task.role]


# ------------------------------------------------------------------ registry and estimators

def test_an_unknown_model_names_the_known_ones():
    with pytest.raises(ValueError, match=r"no force model named 'gp_magic'; known: \["):
        build_model("force", "gp_magic")
    with pytest.raises(ValueError, match="bad hyperparameters for force model 'paper'"):
        build_model("force", "paper", {"subsampel": 10})


def test_model_hyperparameters_are_the_ones_beside_the_chosen_model():
    name, hyper = model_settings(TaskModels.model_validate(
        {"model": "random_forest", "paper": {"subsample": 5},
         "random_forest": {"n_estimators": 7}}))
    assert (name, hyper) == ("random_forest", {"n_estimators": 7})
    model = build_model("force", name, hyper)
    assert model.steps[-1][1].n_estimators == 7  # behind the standardising steps


@pytest.mark.parametrize("estimator", [SubsampledGaussianProcess(subsample=30), BaselineDelta()],
                         ids=lambda e: type(e).__name__)
def test_custom_estimators_follow_the_scikit_learn_contract(estimator):
    check_estimator(estimator)


def test_subsampled_gp_keeps_every_force_level(project):
    frame = features(project)
    y = get_task("single_force", "force").target_values(frame)["force"]
    gp = SubsampledGaussianProcess(subsample=60, random_state=0).fit(frame[CHANNELS], y)
    assert len(gp.subsample_index_) == 60
    assert set(y[gp.subsample_index_]) == set(y)


def test_baseline_features_are_zero_mean_on_rest_samples(project):
    frame = pd.read_parquet(project[1] / "processed" / "single_force.parquet")
    featurizer = fit_featurizer("baseline", frame, "single_force", PAPER_SKIN)
    rest = (frame["stretch"] == 1.0) & ((frame["force"] == 0) | (frame["x"] == 0))
    delta = featurizer.transform(frame.loc[rest, CHANNELS])
    assert np.allclose(delta.mean(axis=0), 0.0, atol=1e-9)


# ------------------------------------------------------------------ cross-validation and metrics

def test_out_of_fold_predictions_cover_each_row_once(project, capsys):
    """… and the folds' progress is shown as they finish (issue 21: training was silent)."""
    frame = features(project)
    task = get_task("single_force", "localise")
    folds = assign_folds(frame, "single_force", "stratified", 10, seed=42, skin=PAPER_SKIN)
    result = cross_validate(task, frame, folds, build_model("localise", "paper",
                                                            {"n_estimators": 10}), "stratified",
                            PAPER_SKIN, progress="scene/localise CV")
    assert "scene/localise CV" in capsys.readouterr().err
    assert len(result.predictions) == task.rows(frame).sum()
    assert result.predictions[["x_pred", "y_pred"]].notna().all().all()
    assert len(result.per_fold["x"]) == 10
    confusion = np.array(result.confusion["x"]["counts"])
    assert confusion.sum() == len(result.predictions)
    accuracy = (result.predictions["x_pred"] == result.predictions["x_true"]).mean()
    assert result.summary["x"]["accuracy"] == pytest.approx(accuracy, abs=0.02)


@pytest.mark.heavy
def test_same_params_and_seed_give_identical_scores_files(project, tmp_path):
    # force: the seeded default (gradient boosting's random_state); localise's default,
    # logistic regression, draws nothing
    for task in ("force",):
        train(project, "single_force", task, tmp_path / "a" / task)
        train(project, "single_force", task, tmp_path / "b" / task)
        first = (tmp_path / "a" / task / "scores.json").read_bytes()
        assert first == (tmp_path / "b" / task / "scores.json").read_bytes(), task
        assert json.loads(first)["status"] == "trained"


def test_scores_carry_every_score_under_both_schemes_and_metrics_the_headline(project,
                                                                            tmp_path):
    train(project, "single_force", "localise", tmp_path)
    metrics = json.loads((tmp_path / "scores.json").read_text())
    for scheme in ("stratified", "conditions"):
        for axis in ("x", "y"):
            scores = metrics[scheme][axis]
            assert {"accuracy", "balanced_accuracy", "f1_macro", "within_one",
                    "accuracy_std"} <= set(scores)
            assert 0 <= scores["accuracy"] <= scores["within_one"] <= 1
        assert len(metrics["confusion"][scheme]["x"]["counts"]) == 10  # x = 1..10
    assert metrics["dataset_md5"] == md5_file(project[1] / "processed" / "single_force.parquet")
    oof = pd.read_parquet(tmp_path / "oof.parquet")
    assert set(oof["scheme"]) == {"stratified", "conditions"}
    # DVC's metrics (the report writes them): the conditions-CV accuracy of each axis, nothing else
    from eskin.reporting.report import headline_metrics
    assert headline_metrics({"single_force": {"localise": metrics}}) == {"single_force": {
        "localise": {axis: {"accuracy": metrics["conditions"][axis]["accuracy"]}
                     for axis in ("x", "y")}}}


@pytest.mark.heavy
def test_detection_keeps_a_score_per_sample_for_roc_curves(project, tmp_path):
    train(project, "single_force", "detect", tmp_path)
    oof = pd.read_parquet(tmp_path / "oof.parquet")
    assert oof["contact_score"].notna().all()
    metrics = json.loads((tmp_path / "scores.json").read_text())
    assert 0.5 < metrics["stratified"]["contact"]["roc_auc"] <= 1
    assert metrics["source"] == "simulated (seed 20230529)"
    assert metrics["dataset_rows"] == len(oof) // 2


@pytest.mark.heavy
def test_two_force_tasks_train(project, tmp_path):
    summary = train(project, "two_force", "localise", tmp_path / "loc")
    scores = json.loads((tmp_path / "loc" / "scores.json").read_text())
    assert set(scores["stratified"]) == {"x1", "y1", "x2", "y2"}, summary
    train(project, "two_force", "force", tmp_path / "f")
    scores = json.loads((tmp_path / "f" / "scores.json").read_text())
    assert np.isfinite(scores["conditions"]["force1"]["r2"])
    assert np.isfinite(scores["conditions"]["force2"]["r2"])
    train(project, "two_force", "stretch", tmp_path / "stretch")
    scores = json.loads((tmp_path / "stretch" / "scores.json").read_text())
    assert scores["status"] == "skipped" and "two or more stretch levels" in scores["reason"]
    # the default scene records fewer contacts too (contact_counts): detect counts them
    train(project, "two_force", "detect", tmp_path / "detect")
    scores = json.loads((tmp_path / "detect" / "scores.json").read_text())
    assert scores.get("status") != "skipped", scores
    assert 0.5 < scores["conditions"]["contacts"]["accuracy"] <= 1.0


def test_a_task_model_may_be_named_per_kind():
    section = TaskModels.model_validate(
        {"model": {"single_force": "logistic", "two_force": "paper"}, "logistic": {"C": 2.0}})
    assert model_settings(section, "tuned", "single_force") == ("logistic", {"C": 2.0})
    assert model_settings(section, "tuned", "two_force") == ("paper", {})
    with pytest.raises(KeyError, match="no model for"):
        model_settings(TaskModels.model_validate({"model": {"single_force": "logistic"}}),
                       "tuned", "two_force")


@pytest.mark.parametrize("configuration", ["tuned", "paper"])
def test_a_scenes_settings_choose_what_the_whole_section_chooses(repo_params, configuration):
    """The settings stage's part of each train.<task> section gives every kind, on a
    row/column skin and on a channel array, the model and hyperparameters the whole
    section gives."""
    from eskin.learning.choice import model_for_skin, task_section
    from eskin.skin import Skin, skin_from_dict

    array = skin_from_dict({"channels": [f"m{i}" for i in range(15)],
                            "x_mm": [0.0, 8.0, 16.0], "y_mm": [0.0, 8.0, 16.0]})
    sections = [repo_params["train"][task] for task in ("stretch", "force", "detect", "localise")]
    # and a knob of the model a skin of long axes trains instead
    sections.append({**repo_params["train"]["localise"], "peak_window": {"C": 3.0}})
    for task, section in zip(("stretch", "force", "detect", "localise", "localise"), sections,
                             strict=True):
        whole = TaskModels.model_validate(section)
        for kind in ("single_force", "two_force"):
            part = TaskModels.model_validate(task_section(whole, configuration, kind))
            chosen = model_settings(whole, configuration, kind)
            assert model_settings(part, configuration, kind) == chosen
            for skin in (PAPER_SKIN, array, Skin(32, 32)):
                assert model_for_skin(part, *chosen, skin, task, kind) == \
                    model_for_skin(whole, *chosen, skin, task, kind), (task, kind)


def test_a_knob_of_one_kinds_model_leaves_the_other_kinds_settings_file_as_it_was(
        repo_params, tmp_path):
    """What lets `-S train.force.physics_profile.max_iter=150` rerun the single-force
    force stage only: the two-force scene's settings file keeps its bytes."""
    import copy

    from eskin.learning.settings import write_settings

    changed = copy.deepcopy(repo_params["train"]["force"])
    changed["physics_profile"]["max_iter"] += 1
    files = {}
    for name, section in (("before", repo_params["train"]["force"]), ("after", changed)):
        for kind in ("single_force", "two_force"):
            path = tmp_path / name / f"{kind}.json"
            write_settings(path, scene=kind, kind=kind, task="force", configuration="tuned",
                           task_params=TaskModels.model_validate(section))
            files[name, kind] = path.read_bytes()
    assert files["before", "single_force"] != files["after", "single_force"]
    assert files["before", "two_force"] == files["after", "two_force"]


def test_node_ids_are_row_major():
    ids = PAPER_SKIN.node_id(np.array([0, 1, 1, 10]), np.array([0, 1, 10, 10]))
    assert ids.tolist() == [0, 1, 10, 100]


def test_the_paper_configuration_switch_picks_every_tasks_paper_entry():
    section = TaskModels.model_validate({"model": "hist_gradient_boosting",
                                         "paper": {"subsample": 10},
                                         "hist_gradient_boosting": {"max_iter": 5}})
    assert model_settings(section) == ("hist_gradient_boosting", {"max_iter": 5})
    assert model_settings(section, "paper") == ("paper", {"subsample": 10})
    with pytest.raises(ValueError, match="train.configuration"):
        model_settings(section, "best")


@pytest.mark.parametrize("backend", ["sequential", "threading", "loky"])
def test_folds_give_the_same_predictions_on_every_joblib_backend(backend, project):
    """cv.backend: a Dask or Ray cluster would take the folds through the same joblib path."""
    frame, kind = features(project), "single_force"
    task_ = get_task(kind, "force")
    folds = assign_folds(frame, kind, "conditions", 4, 0, skin=PAPER_SKIN)
    estimator = build_model("force", "hist_gradient_boosting",
                            {"max_iter": 20, "learning_rate": 0.1, "seed": 0})
    with parallel_backend("sequential"):
        reference = cross_validate(task_, frame, folds, estimator, "conditions", PAPER_SKIN,
                                   n_jobs=1)
    with parallel_backend(backend):
        result = cross_validate(task_, frame, folds, estimator, "conditions", PAPER_SKIN,
                                n_jobs=2)
    pd.testing.assert_frame_equal(result.predictions, reference.predictions)
    assert result.per_fold == reference.per_fold


def test_folds_left_when_a_cluster_loses_their_shared_data_run_after_it_is_sent_again(
        project, monkeypatch, capsys):
    """A Dask cluster that loses the data the folds share (its last copy on a killed worker:
    FutureCancelledError, "already forgotten") gets it again, and the folds not yet done
    run; the predictions are those of a sweep that lost nothing. A cluster that keeps
    losing it is an error after SHARED_DATA_SENDS sends."""
    from distributed.client import FutureCancelledError
    from joblib import Parallel

    from eskin.evaluation import crossval

    frame, kind = features(project), "single_force"
    task_ = get_task(kind, "force")
    folds = assign_folds(frame, kind, "conditions", 4, 0, skin=PAPER_SKIN)
    estimator = build_model("force", "hist_gradient_boosting",
                            {"max_iter": 20, "learning_rate": 0.1, "seed": 0})

    def sweep():
        with parallel_backend("sequential"):
            return cross_validate(task_, frame, folds, estimator, "conditions", PAPER_SKIN,
                                  n_jobs=2, probe=False)

    reference = sweep()
    sends, asked = [], []

    class Losing:  # as a cluster: the folds' outcomes, then the data lost
        def __init__(self, *args, **kwargs):
            self.parallel = Parallel(n_jobs=1, return_as="generator")

        def __call__(self, calls):
            calls = list(calls)
            asked.append(len(calls))
            for i, outcome in enumerate(self.parallel(calls)):
                if i == losing["at"] and losing["times"]:
                    losing["times"] -= 1
                    raise FutureCancelledError("batch-1", "already forgotten")
                yield outcome

    monkeypatch.setattr(crossval, "Parallel", Losing)
    monkeypatch.setattr(crossval, "_shared_with_cluster",
                        lambda *data: sends.append(1) or contextlib.ExitStack())
    losing = {"at": 2, "times": 1}  # lost once, after two folds
    result = sweep()
    pd.testing.assert_frame_equal(result.predictions, reference.predictions)
    assert asked == [4, 2] and len(sends) == 2  # the two folds left, after a second send
    assert "lost the data the folds share" in capsys.readouterr().err
    losing.update(at=0, times=crossval.SHARED_DATA_SENDS)  # lost at every send
    with pytest.raises(FutureCancelledError):
        sweep()


@pytest.mark.heavy  # starts a loky pool
def test_the_first_fold_decides_whether_the_rest_go_to_the_pool(project, monkeypatch):
    """Folds go to the workers when the time they save on the remaining folds exceeds the
    pool's start; the predictions are the same either way."""
    from eskin.evaluation import crossval

    # 20 folds of 0.7 s (the force model's) save more than the pool costs; of 0.02 s not
    assert crossval.pool_pays(0.7, 19, 2) and not crossval.pool_pays(0.02, 19, 2)
    assert not crossval.pool_pays(10.0, 0, 2)  # nothing left to share
    frame, kind = features(project), "single_force"
    task_ = get_task(kind, "force")
    folds = assign_folds(frame, kind, "conditions", 4, 0, skin=PAPER_SKIN)
    estimator = build_model("force", "hist_gradient_boosting",
                            {"max_iter": 20, "learning_rate": 0.1, "seed": 0})
    runs = {}
    for starts_s in (1e6, 0.0):  # a pool that never pays, one that always does
        monkeypatch.setattr(crossval, "POOL_STARTS_S", starts_s)
        runs[starts_s] = cross_validate(task_, frame, folds, estimator, "conditions",
                                        PAPER_SKIN, n_jobs=2, probe=True)
    assert not runs[1e6].pooled and runs[0.0].pooled
    pd.testing.assert_frame_equal(runs[1e6].predictions, runs[0.0].predictions)
    # a fold's seconds from the last run decide instead, against what a first fold would
    for starts_s, fold_s, pooled in ((1e6, 1e9, True), (0.0, 0.0, False)):
        monkeypatch.setattr(crossval, "POOL_STARTS_S", starts_s)
        known = cross_validate(task_, frame, folds, estimator, "conditions", PAPER_SKIN,
                               n_jobs=2, probe=True, fold_seconds=fold_s)
        assert known.pooled is pooled
        pd.testing.assert_frame_equal(known.predictions, runs[0.0].predictions)
    assert runs[0.0].fold_seconds > 0


def test_ray_is_no_backend_and_params_say_which_are(repo_params):
    """Ray was dropped for Dask (docs/lab.md): params.yaml naming it is one line
    listing the backends there are."""
    import copy

    from eskin.config.base import validate_params
    from eskin.config.params import Params

    params = copy.deepcopy(repo_params)
    params["cv"]["backend"] = "ray"
    with pytest.raises(ValueError, match=r"cv\.backend.*'dask'"):
        validate_params(params, Params)


def test_force_profile_reads_stretch_and_press_in_any_units(repo_params):
    """The physics features: a stretch estimate that follows the stretch whatever the press,
    a press peak that rises with the force, and the same features (and predictions) in
    counts as in farads or offset by a constant."""
    from eskin.data.plan import single_force_plan
    from eskin.device.physics import SkinParams
    from eskin.learning.estimators import ForceProfile
    from harness.calibrate import simulate_plan

    sim = SkinParams.from_mapping(repo_params["sim"])
    plan = single_force_plan("t", [1.0, 1.15842], [0.0, 1.2936, 5.2136], samples=2)
    frame = simulate_plan(sim, plan, seed=3)
    force = get_task("single_force", "force").target_values(frame)["force"]
    X = frame[CHANNELS]  # by name: the x and y terminals
    features = ForceProfile().fit(X, force).transform(X)
    stretch, peak_x = features[:, 20], features[:, 21]
    assert np.corrcoef(stretch, frame["stretch"])[0, 1] > 0.95
    at_rest = frame["stretch"].to_numpy() == 1.0
    means = [peak_x[at_rest & (force == f)].mean() for f in (0.0, 1.2936, 5.2136)]
    assert means[0] < means[1] < means[2], means
    for other_units in (X * 1e-12, X + 1e6):  # farads; an offset
        assert np.allclose(ForceProfile().fit(other_units, force).transform(other_units),
                           features, atol=1e-5)
        predictions = [build_model("force", "physics_profile", {"max_iter": 20}, PAPER_SKIN)
                       .fit(data, force).predict(data) for data in (X, other_units)]
        assert np.allclose(*predictions, atol=1e-9 * np.ptp(force))


@pytest.mark.parametrize("rows, columns", [(15, 3), (3, 2)])
def test_peak_window_locates_each_axis_from_its_own_terminals(repo_params, rows, columns):
    """PeakWindow learns which axis locates its target (the one whose highest terminal is
    the node most often) and reads the node from the terminals around the highest, on a
    skin whose axes differ in length: along an axis where it is trained (over 14
    terminals) as well as the multinomial logistic regression on every channel, within a
    point; along an axis shorter than its window, still three in four (on these few
    trials)."""
    from sklearn.model_selection import GroupShuffleSplit

    from eskin.data.plan import single_force_plan
    from eskin.data.schema import contact_mask
    from eskin.device.physics import SkinParams
    from eskin.learning.estimators import PeakWindow
    from eskin.skin import Skin
    from harness.calibrate import simulate_plan

    skin = Skin(rows, columns)
    sim = SkinParams.from_mapping(repo_params["sim"])
    plan = single_force_plan("t", [1.0, 1.15842], [1.2936, 5.2136], samples=4, skin=skin,
                             repeats=2)
    frame = simulate_plan(sim, plan, seed=7)
    frame = frame[contact_mask(frame)].reset_index(drop=True)
    train, test = next(GroupShuffleSplit(1, test_size=0.25, random_state=0).split(
        frame, groups=frame["trial"]))
    X = frame[skin.channels]
    for target, axis in (("x", (0, rows)), ("y", (rows, rows + columns))):
        model = PeakWindow().fit(X.iloc[train], frame[target].iloc[train])
        assert model.axis_ == axis
        found = model.predict(X.iloc[test])
        assert set(found) <= set(frame[target])
        truth = frame[target].iloc[test].to_numpy()
        ours = np.mean(found == truth)
        long_axis = axis[1] - axis[0] > 14
        assert ours > (0.9 if long_axis else 0.75), (target, ours)
        if long_axis:
            reference = build_model("localise", "logistic").fit(X.iloc[train],
                                                               frame[target].iloc[train])
            theirs = np.mean(reference.predict(X.iloc[test]) == truth)
            assert ours > theirs - 0.01, (target, ours, theirs)


def test_peak_window_refuses_positions_that_are_not_node_numbers():
    from eskin.learning.estimators import PeakWindow

    X = pd.DataFrame(np.random.default_rng(0).normal(size=(40, 20)), columns=CHANNELS)
    with pytest.raises(ValueError, match="node numbers"):
        PeakWindow().fit(X, np.linspace(1.0, 10.0, 40))
    with pytest.raises(ValueError, match="cx1..cxR"):
        PeakWindow().fit(X.to_numpy(), np.arange(40) % 10 + 1)


def test_the_last_runs_record_says_whether_the_next_runs_folds_go_to_a_pool(project, tmp_path,
                                                                         monkeypatch):
    """The train step records a fold's seconds per scheme, with the model; the next run of
    that model hands them to the cross-validation (which then runs no fold first to time
    it), and a run of another model, or an unreadable record, does not."""
    from eskin.learning import train as training

    handed = []

    def spy(*args, **kwargs):
        handed.append(kwargs.get("fold_seconds"))
        return cross_validate(*args, **kwargs)

    monkeypatch.setattr(training, "cross_validate", spy)
    record = tmp_path / "record.json"
    train(project, "single_force", "stretch", tmp_path, record_path=record)
    first = json.loads(record.read_text())
    schemes = list(project[0]["cv"]["schemes"])
    assert handed == [None] * len(schemes)  # no record yet: the first fold times the rest
    assert set(first["fold_seconds"]) == set(schemes) and first["model"]
    assert all(seconds > 0 for seconds in first["fold_seconds"].values())
    handed.clear()
    train(project, "single_force", "stretch", tmp_path, record_path=record)
    assert handed == [first["fold_seconds"][scheme] for scheme in schemes]
    handed.clear()
    record.write_text(json.dumps({**first, "model": "another"}))
    train(project, "single_force", "stretch", tmp_path, record_path=record)
    record.write_text("{ half written")
    train(project, "single_force", "stretch", tmp_path, record_path=record)
    assert handed == [None] * (2 * len(schemes))
