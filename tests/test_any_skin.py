"""Any skin after ingest (issue 37): features, models, folds, scores, the report, the ONNX
stack and the live view follow the skin a dataset was taken on — a row/column R × C skin,
or a channel array (named channels, press positions on a grid, in mm)."""

import json
from types import SimpleNamespace

import numpy as np
import onnx
import pandas as pd
import pytest
import yaml
from conftest import typed
from sklearn.base import clone
from sklearn.model_selection import StratifiedKFold

from eskin.catalog import (
    METRICS,
    TASK_NAMES,
    export_report_path,
    features_path,
    featurizer_path,
    folds_path,
    model_path,
    processed_path,
    stack_path,
    task_outputs,
)
from eskin.config.report import Report
from eskin.config.scenes import ChannelArraySkin, RowColumnSkin
from eskin.config.train import TaskModels
from eskin.data.schema import dataset_skin, md5_file, write_dataset
from eskin.deploy.stack import ExportedStack, SkinStack
from eskin.deploy.view import LiveView
from eskin.evaluation.folds import (
    coarser_strata,
    draw_folds,
    read_fold_notes,
    strata,
)
from eskin.evaluation.metrics import position_error_mm
from eskin.learning.choice import model_for_skin
from eskin.learning.estimators import (
    ActiveTerminals,
    ForceProfile,
    build_model,
)
from eskin.reporting import figures, page, report
from eskin.skin import ChannelArray, Skin, skin_from_dict
from eskin.steps.export import export_at
from eskin.steps.featurize import featurize_at
from eskin.steps.folds import folds_at
from eskin.steps.train import train_at

SAMPLES = 4
# 15 channels, 5 magnetometers × xyz, pressed on a 3 × 3 grid placed in mm: a public
# magnetic skin's recording, as the importer writes it.
MAGNETIC = {"channels": [f"m{i}{axis}" for i in range(1, 6) for axis in "xyz"],
            "x_mm": [0.0, 12.5, 25.0], "y_mm": [0.0, 10.0, 20.0]}


def provenance(frame: pd.DataFrame, trial: int) -> pd.DataFrame:
    return frame.assign(session="s1", trial=f"t{trial:04d}", sample=np.arange(len(frame)),
                        seq=np.arange(len(frame)) + 1000 * trial, t_ms=np.arange(len(frame)))


def row_column_dataset(skin: Skin, nodes_x, nodes_y, seed: int = 0) -> pd.DataFrame:
    """Single-force samples of a row/column skin: each terminal's own baseline, scaled by
    the stretch; a press lifts the terminals around its node on each axis, more with
    force; rest trials at node 0."""
    rng = np.random.default_rng(seed)
    base = rng.uniform(480, 520, skin.terminals)
    blocks = []
    conditions = [(stretch, 0, 0, 0.0) for stretch in (1.0, 1.1) for _ in range(3)]
    conditions += [(stretch, x, y, force) for stretch in (1.0, 1.1) for x in nodes_x
                   for y in nodes_y for force in (1.5, 4.0)]
    for trial, (stretch, x, y, force) in enumerate(conditions):
        press = np.zeros(skin.terminals)
        if x:
            for start, at, width in ((0, x, skin.rows), (skin.rows, y, skin.columns)):
                terminal = np.arange(1, width + 1)
                press[start:start + width] = 10 * force * np.exp(-0.5 * (terminal - at) ** 2)
        counts = base * stretch + press + rng.normal(0, 0.8, (SAMPLES, skin.terminals))
        frame = pd.DataFrame(counts, columns=skin.channels).assign(
            force=force, x=x, y=y, stretch=stretch)
        blocks.append(provenance(frame, trial))
    return pd.concat(blocks, ignore_index=True)


def magnetic_dataset(skin: ChannelArray, seed: int = 0) -> pd.DataFrame:
    """A magnetic skin's single-force recording: each press position bends the field at
    the magnetometers near it, in proportion to a continuous force; untouched frames are
    node 0 at 0 N; one stretch (an import has none)."""
    rng = np.random.default_rng(seed)
    sensors = rng.uniform(0, 25, (5, 2))
    rest = rng.normal(0, 50, skin.terminals)
    blocks = []
    positions = [(0, 0)] * 6 + [(x, y) for x in range(1, 4) for y in range(1, 4)] * 3
    for trial, (x, y) in enumerate(positions):
        force = 0.0 if x == 0 else rng.uniform(0.5, 6.0) * rng.uniform(0.8, 1.0, SAMPLES)
        field = np.zeros(skin.terminals)
        if x:
            at = np.array([skin.x_mm[x - 1], skin.y_mm[y - 1]])
            for i, sensor in enumerate(sensors):
                offset = at - sensor
                weight = np.exp(-np.sum(offset ** 2) / 150)
                field[3 * i:3 * i + 3] = 30 * weight * np.array([*offset / 10, 1.0])
        counts = rest + np.outer(np.ones(SAMPLES) * (force if x else 0.0), field) \
            + rng.normal(0, 0.5, (SAMPLES, skin.terminals))
        frame = pd.DataFrame(counts, columns=skin.channels).assign(
            force=force, x=x, y=y, stretch=1.0)
        blocks.append(provenance(frame, trial))
    return pd.concat(blocks, ignore_index=True)


@pytest.fixture(scope="module")
def params(repo_params):
    """The repo's training sections, lighter, on three folds run in this process."""
    import copy

    params = copy.deepcopy(repo_params)
    params["cv"].update(folds=3, n_jobs=1, backend="sequential")
    params["train"]["force"]["physics_profile"]["max_iter"] = 30
    params["train"]["force"]["hist_gradient_boosting"]["max_iter"] = 30
    params["train"]["detect"]["hist_gradient_boosting"]["max_iter"] = 30
    return typed(params)


def run_pipeline(root, scene: str, frame: pd.DataFrame, skin, spec, params) -> dict:
    """The steps after ingest, as their stages run them: featurize, train every task,
    export the stack (checked against scikit-learn's), report."""
    write_dataset(frame, "single_force", root / processed_path(scene),
                  {"kind": "single_force", "scene": scene,
                   "source": {"kind": "import", "path": "lab.csv", "sha256": "0" * 64}},
                  skin=skin)
    featurize_at(scene, root / "data/processed", root / "data/features", root / "models",
                 settings=params.featurize)
    folds_at(root / features_path(scene), root / folds_path(scene),
             schemes=list(params.cv.schemes), n_splits=int(params.cv.folds),
             seed=int(params.cv.seed), scene=scene)
    trained = {}
    for task in TASK_NAMES:
        trained[task] = train_at(
            scene, task, task_params=getattr(params.train, task),
            configuration=params.train.configuration, cv=params.cv,
            features_dir=root / "data/features",
            **{name: root / path for name, path in task_outputs(scene, task).items()})
    # dvc.lock as DVC records the outputs the stack is loaded from (their md5s)
    outs = [featurizer_path(scene), *(model_path(scene, task) for task in TASK_NAMES)]
    (root / "dvc.lock").write_text(yaml.safe_dump({"stages": {"train": {"outs": [
        {"path": path.as_posix(), "md5": md5_file(root / path)} for path in outs]}}}))
    exported = export_at(scene, root)
    reported = report.report(
        report=Report(schemes=["stratified", "conditions"], plots_scheme="stratified", dpi=40,
                      page_dpi=30),
        scenes={scene: SimpleNamespace(kind="single_force", skin=spec)},
        scores_dir=root / "reports/scores", predictions_dir=root / "reports/predictions",
        figures_dir=root / "reports/figures", plots_dir=root / "reports/plots",
        page_path=root / "reports/index.html", results_path=root / "reports/results.md",
        metrics_path=root / METRICS)
    scores = {task: json.loads((root / task_outputs(scene, task)["scores_path"]).read_text())
              for task in TASK_NAMES}
    return {"trained": trained, "exported": exported, "reported": reported, "scores": scores}


@pytest.mark.parametrize("rows, columns, nodes_x, nodes_y",
                         [(8, 8, [1, 3, 6, 8], [1, 4, 8]), (16, 12, [1, 6, 11, 16], [1, 6, 12])],
                         ids=["8x8", "16x12"])
@pytest.mark.heavy
def test_a_row_column_skin_of_any_size_goes_from_features_to_the_stack(
        rows, columns, nodes_x, nodes_y, params, tmp_path):
    skin = Skin(rows, columns)
    spec = RowColumnSkin(rows=rows, columns=columns)
    done = run_pipeline(tmp_path, "lab", row_column_dataset(skin, nodes_x, nodes_y), skin,
                        spec, params)
    assert dataset_skin(tmp_path / features_path("lab")) == skin
    scores = done["scores"]
    assert scores["force"]["model"] == "physics_profile"  # per axis, on any R × C
    assert "model_note" not in scores["force"]
    assert all(scores[task]["status"] == "trained" for task in TASK_NAMES)
    assert scores["force"]["conditions"]["force"]["r2"] > 0.8
    assert min(scores["localise"]["conditions"][t]["accuracy"] for t in ("x", "y")) > 0.8
    assert "position" not in scores["localise"]["conditions"]  # no mm on a row/column skin
    # the stack reads the skin's terminals, and says which skin it is for
    stack = ExportedStack.from_file(tmp_path / stack_path("lab"))
    assert stack.skin == skin
    dims = onnx.load(tmp_path / stack_path("lab")).graph.input[0].type.tensor_type.shape.dim
    assert dims[1].dim_value == rows + columns
    check = json.loads((tmp_path / export_report_path("lab")).read_text())
    assert all(e["differing_alone"] == 0 for e in check["estimates"].values()), check
    # the report names the skin, and its nodes are terminals
    results = (tmp_path / "reports/results.md").read_text()
    assert f"skin: {rows} × {columns} row/column skin ({rows + columns} terminals)" in results
    panels = pd.read_csv(tmp_path / "reports/plots/confusion/lab_x.csv")["panel"]
    assert set(panels) == {"lab: x terminal"}
    assert (tmp_path / "reports/figures/lab/localisation_confusion_conditions.png").exists()


@pytest.mark.heavy
def test_a_magnetic_channel_array_trains_generic_models_and_scores_in_mm(params, tmp_path):
    """15 magnetometer channels on a 3 × 3 grid in mm, continuous force, node 0 untouched:
    featurize → every single-force task → report → export."""
    spec = ChannelArraySkin.model_validate(MAGNETIC)
    skin = skin_from_dict(MAGNETIC)
    done = run_pipeline(tmp_path, "magnetic", magnetic_dataset(skin), skin, spec, params)
    assert dataset_skin(tmp_path / features_path("magnetic")) == skin
    scores, trained = done["scores"], done["trained"]
    # the physics model reads row/column terminals: the generic booster, said in one line
    assert scores["force"]["model"] == "hist_gradient_boosting"
    assert "physics_profile reads a row/column skin" in scores["force"]["model_note"]
    note = [line for line in trained["force"].summary.splitlines() if "physics_profile" in line]
    assert len(note) == 1 and "trained hist_gradient_boosting instead" in note[0]
    assert scores["stretch"]["status"] == "skipped"  # one stretch: the reason, as ever
    assert "two or more stretch levels" in scores["stretch"]["reason"]
    assert scores["force"]["conditions"]["force"]["r2"] > 0.5
    assert scores["detect"]["conditions"]["contact"]["accuracy"] > 0.8
    # the localisation error in mm, beside accuracy: the mean distance per fold
    oof = pd.read_parquet(tmp_path / task_outputs("magnetic", "localise")["predictions_path"])
    for scheme in ("stratified", "conditions"):
        rows = oof[oof["scheme"] == scheme]
        x_mm, y_mm = np.array(skin.x_mm), np.array(skin.y_mm)
        per_fold = [np.hypot(x_mm[f["x_true"] - 1] - x_mm[f["x_pred"] - 1],
                             y_mm[f["y_true"] - 1] - y_mm[f["y_pred"] - 1]).mean()
                    for _, f in rows.groupby("fold")]
        position = scores["localise"][scheme]["position"]
        assert position["error_mm"] == pytest.approx(np.mean(per_fold), rel=1e-9)
        assert position["error_mm_std"] == pytest.approx(np.std(per_fold), rel=1e-9)
        assert "accuracy" in scores["localise"][scheme]["x"]
    assert "position error" in trained["localise"].summary
    # the report names the skin, shows the error in mm; a node is a press position
    results = (tmp_path / "reports/results.md").read_text()
    assert "skin: array of 15 channels, 3 × 3 press positions" in results
    assert "| localisation error (mm) [logistic] |" in results
    page = (tmp_path / "reports/index.html").read_text()
    assert "Skin: array of 15 channels, 3 × 3 press positions." in page
    panels = pd.read_csv(tmp_path / "reports/plots/confusion/magnetic_y.csv")["panel"]
    assert set(panels) == {"magnetic: y position"}
    # the stack: 15 channels in, the skin in its metadata, its estimates scikit-learn's
    path = tmp_path / stack_path("magnetic")
    exported = ExportedStack.from_file(path)
    assert exported.skin == skin
    props = {p.key: p.value for p in onnx.load(path).metadata_props}
    assert json.loads(props["eskin.skin"]) == skin.as_dict()
    workspace = SkinStack.from_workspace("magnetic", tmp_path)
    frames = pd.read_parquet(tmp_path / processed_path("magnetic"))[skin.channels].to_numpy()
    pd.testing.assert_frame_equal(exported.predict(frames[:50]), workspace.predict(frames[:50]),
                                  rtol=1e-9)


def test_the_physics_features_read_each_axis_of_a_rectangular_skin():
    """A press at x 3, y 10 of an 8 × 12 skin: the peak of the x terminals is the 3rd, of
    the y terminals the 10th (read as two halves of 10, both would be wrong)."""
    skin = Skin(8, 12)
    rng = np.random.default_rng(1)
    X = pd.DataFrame(rng.normal(500, 1, (60, 20)), columns=skin.channels)
    pressed = X.copy()
    pressed[["cx3", "cy10"]] += 40
    y = np.r_[np.zeros(60), np.full(60, 3.0)]
    both = pd.concat([X, pressed], ignore_index=True)
    features = ForceProfile().fit(both, y).transform(pressed)
    n = skin.terminals
    x_top, y_top = features[:, n + 4], features[:, n + 8]
    assert (x_top == 2).all() and (y_top == 9).all()
    peaks = ActiveTerminals().fit(both).transform(pressed)
    # the two strongest peaks of each axis (lower terminal first): the press among them
    assert (peaks[:, n:n + 2] == 2).any(axis=1).all()
    assert (peaks[:, n + 5:n + 7] == 9).any(axis=1).all()


def test_the_physics_models_are_scikit_learn_estimators_built_for_the_skin():
    skin = Skin(16, 12)
    model = build_model("force", "physics_profile", {"quiet": 2}, skin)
    assert len(model[-1].monotonic_cst) == skin.terminals + 9
    copy = clone(model)
    assert copy.get_params()["forceprofile__quiet"] == 2
    assert copy[-1].monotonic_cst == model[-1].monotonic_cst


def test_the_force_models_quiet_terminals_follow_the_skin_unless_set(repo_params):
    """The repo's params set no quiet terminals: each skin gets those a press leaves alone,
    and the paper's 10 × 10 keeps the 3 it had (its model unchanged)."""
    hyper = repo_params["train"]["force"]["physics_profile"]
    assert "quiet" not in hyper
    quiet = {size: build_model("force", "physics_profile", hyper, Skin(*size))
             .get_params()["forceprofile__quiet"] for size in
             [(2, 2), (2, 9), (6, 6), (7, 12), (10, 10), (32, 32)]}
    assert quiet == {(2, 2): 1, (2, 9): 1, (6, 6): 1, (7, 12): 2, (10, 10): 3, (32, 32): 3}
    assert build_model("force", "physics_profile", {**hyper, "quiet": 2}, Skin(10, 10)
                       ).get_params()["forceprofile__quiet"] == 2


@pytest.mark.heavy
def test_a_2x2_skin_trains_every_task_with_the_default_params(params, tmp_path):
    """Issue 59: the shared quiet: 3 refused a 2 × 2 skin. A press covers its every
    terminal, so none is quiet and the stretch estimate carries the press too: its scores
    here (conditions CV: force R² 0.70, x/y accuracy 0.71 of 2 nodes) are below the
    larger skins', above chance."""
    skin = Skin(2, 2)
    done = run_pipeline(tmp_path, "lab", row_column_dataset(skin, [1, 2], [1, 2]), skin,
                        RowColumnSkin(rows=2, columns=2), params)
    scores = done["scores"]
    assert all(scores[task]["status"] == "trained" for task in TASK_NAMES)
    assert scores["force"]["model"] == "physics_profile"
    assert scores["force"]["conditions"]["force"]["r2"] > 0.6
    assert min(scores["localise"]["conditions"][t]["accuracy"] for t in ("x", "y")) > 0.6
    assert ExportedStack.from_file(tmp_path / stack_path("lab")).skin == skin


def test_a_model_that_reads_terminals_refuses_what_has_none():
    array = skin_from_dict(MAGNETIC)
    X = np.random.default_rng(2).normal(size=(40, 15))
    with pytest.raises(ValueError, match=r"reads a row/column skin's terminals by name"):
        ForceProfile().fit(X)                                     # no names
    with pytest.raises(ValueError, match=r"got m1x, m1y, m1z, m2x, …"):
        ActiveTerminals().fit(pd.DataFrame(X, columns=array.channels))
    with pytest.raises(ValueError, match=r"has none: use 'hist_gradient_boosting'"):
        build_model("force", "physics_profile", {}, array)
    with pytest.raises(ValueError, match="give build_model the skin"):
        build_model("force", "physics_profile")
    with pytest.raises(ValueError, match=r"quiet terminals per axis must be 1 to 2 .*"
                                         r"train\.force\.physics_profile\.quiet"):
        ForceProfile(quiet=3).fit(pd.DataFrame(X[:, :5], columns=Skin(2, 3).channels))


def test_a_channel_array_trains_the_generic_model_of_a_row_column_one():
    section = TaskModels.model_validate({"model": "physics_profile",
                                         "physics_profile": {"max_iter": 5},
                                         "hist_gradient_boosting": {"max_iter": 7}})
    array = skin_from_dict(MAGNETIC)
    assert model_for_skin(section, "physics_profile", {"max_iter": 5}, Skin(8, 8), "force",
                          "single_force") == ("physics_profile", {"max_iter": 5}, "")
    name, hyper, note = model_for_skin(section, "physics_profile", {"max_iter": 5}, array,
                                       "force", "single_force")
    assert (name, hyper) == ("hist_gradient_boosting", {"max_iter": 7})
    assert note.startswith("physics_profile reads a row/column skin's x and y terminals")
    assert model_for_skin(section, "logistic", {}, array, "localise", "single_force") == (
        "logistic", {}, "")


def test_a_skin_of_long_axes_localises_with_a_model_whose_cost_scales():
    """A localisation's logistic regression on every channel grows with the channels times
    the nodes: past 14 terminals on an axis a one-contact scene trains PeakWindow, and says
    so; a detector's logistic regression (two classes), a two-contact scene (PeakWindow
    locates one contact) and a channel array keep theirs."""
    section = TaskModels.model_validate({"model": "logistic", "logistic": {"C": 1.0},
                                         "peak_window": {"C": 2.0}})
    for skin in (Skin(10, 10), Skin(14, 3), Skin(2, 2)):
        assert model_for_skin(section, "logistic", {"C": 1.0}, skin, "localise",
                              "single_force") == ("logistic", {"C": 1.0}, "")
    for skin in (Skin(15, 4), Skin(32, 32)):
        name, hyper, note = model_for_skin(section, "logistic", {"C": 1.0}, skin, "localise",
                                           "single_force")
        assert (name, hyper) == ("peak_window", {"C": 2.0})
        assert "more than 14 terminals on an axis: trained peak_window instead" in note
    for role, kind in (("detect", "single_force"), ("localise", "two_force")):
        assert model_for_skin(section, "logistic", {"C": 1.0}, Skin(32, 32), role, kind) == (
            "logistic", {"C": 1.0}, "")


def test_strata_number_the_nodes_of_the_datasets_skin():
    """On a 16 × 12 skin, (1, 11) and (2, 1) are two nodes (on the paper's 10 columns
    they would share a number)."""
    frame = pd.DataFrame({"x": [1, 2, 16, 0], "y": [11, 1, 12, 0]})
    assert strata(frame, "single_force", Skin(16, 12)).tolist() == [11, 13, 192, 0]


def test_the_position_error_is_the_mean_distance_in_mm():
    error = position_error_mm([1, 2, 3], [1, 1, 2], [1, 3, 3], [2, 1, 2],
                              (0.0, 3.0, 7.0), (0.0, 4.0))
    assert error == {"error_mm": pytest.approx((4.0 + 4.0 + 0.0) / 3)}
    # an absent contact (node 0) on either side has no distance: left out
    assert position_error_mm([1, 0, 2], [1, 0, 1], [1, 2, 0], [2, 1, 0],
                             (0.0, 3.0), (0.0, 4.0)) == {"error_mm": pytest.approx(4.0)}
    assert np.isnan(position_error_mm([0], [0], [1], [1], (0.0,), (0.0,))["error_mm"])
    with pytest.raises(ValueError, match="a node"):
        position_error_mm([-1], [1], [1], [1], (0.0,), (0.0,))


def test_a_large_confusion_grid_is_coloured_not_written_in():
    rng = np.random.default_rng(3)
    true = rng.integers(1, 33, 500)
    oof = pd.DataFrame({"x_true": true, "x_pred": true, "y_true": true % 12 + 1,
                        "y_pred": true % 12 + 1})
    grid = figures.confusion_grid(oof, ["x", "y"], ["x terminal", "y terminal"])
    x_panel, y_panel = grid.axes[:2]
    assert not x_panel.texts and len(y_panel.texts) == 12  # 32 classes, 12 classes


@pytest.mark.parametrize("skin", [Skin(16, 12), skin_from_dict(MAGNETIC)],
                         ids=["16x12", "channel_array"])
def test_the_live_view_draws_the_skins_map_and_channels(skin):
    with LiveView(scene="lab", kind="single_force", device="sim", skin=skin) as view:
        page = view.page.decode()
    assert f"repeat({skin.size_x}, minmax(0, 2.6em))" in page and f"y <= {skin.size_y}" not in page
    assert f"for (let y = {skin.size_y}; y >= 1; y--)" in page
    assert f"repeat({skin.terminals}, minmax(0, 30px))" in page
    names = json.loads(page.split("const names = ")[1].split(";")[0])
    assert len(names) == skin.terminals
    assert names[0] == ("x1" if skin.row_column else "m1x")


def sampled_once(skin: Skin, stretches=(1.0, 1.07921), forces=(0.0, 1.2936, 3.2536, 5.2136)):
    """Labels of a planned scene with ``samples: 1``: every node at every stretch and
    force, one row a trial, and one rest row a stretch (the measured 32 × 32 scene of
    issue 59: every node 8 rows)."""
    rows = [(stretch, x, y, force) for stretch in stretches for force in forces
            for x, y in skin.nodes()] + [(stretch, 0, 0, 0.0) for stretch in stretches]
    frame = pd.DataFrame(rows, columns=["stretch", "x", "y", "force"])
    return frame.assign(trial=[f"t{i:05d}" for i in range(len(frame))])


def test_folds_a_scene_sampled_once_cannot_stratify_by_node_fall_back_to_blocks():
    """Issue 59: a skin sampled once over two stretches and four forces has 8 rows a node,
    too few for 10 stratified folds; the folds stratify on 2 × 2-node blocks instead, say
    so, and follow cv.seed. (The measured case was 32 × 32; 16 × 16 has the same 8 rows a
    node and a quarter of the rows: 1.9 s here against 10 s.)"""
    skin = Skin(16, 16)
    frame = sampled_once(skin)
    with pytest.raises(ValueError, match="cannot be greater than the number of members"):
        StratifiedKFold(10).split(frame, strata(frame, "single_force", skin)).__next__()
    for scheme in ("stratified", "conditions"):
        folds, note = draw_folds(frame, "single_force", scheme, 10, 42, skin=skin)
        assert note.startswith("stratified on 2 × 2-node blocks, not on the node: every node "
                               "has fewer rows than the 10 folds (at most 8)")
        assert set(folds) == set(range(10))
        blocks = next(coarser_strata(frame, "single_force", skin))[1]
        for fold in range(10):  # each 2 × 2 block has 32 rows: every fold holds each
            assert set(blocks[folds == fold]) >= set(blocks[blocks > 0])
        again, other = (draw_folds(frame, "single_force", scheme, 10, seed, skin=skin)[0]
                        for seed in (42, 43))
        assert np.array_equal(folds, again) and not np.array_equal(folds, other)


def test_folds_fall_back_to_none_where_no_stratum_holds_a_row_a_fold():
    """A 2 × 2 skin, one row a node and three at rest, 5 folds: neither the node nor
    pressed-or-not has 5 rows, so the folds are KFold's; fewer rows than folds is refused
    with the fix."""
    skin = Skin(2, 2)
    frame = sampled_once(skin, stretches=(1.0,), forces=(2.0,))
    frame = pd.concat([frame, frame.tail(1), frame.tail(1)], ignore_index=True)
    frame["trial"] = [f"t{i}" for i in range(len(frame))]
    folds, note = draw_folds(frame, "single_force", "stratified", 5, 0, skin=skin)
    assert note.startswith("not stratified, not on the node")
    assert sorted(np.bincount(folds)) == [1, 1, 1, 2, 2]
    with pytest.raises(ValueError, match="needs at least 10 samples; this dataset has 7: "
                                         "lower cv.folds or acquire more"):
        draw_folds(frame, "single_force", "stratified", 10, 0, skin=skin)


def test_the_folds_file_keeps_the_fallback_for_the_scores_and_the_report(tmp_path):
    """The folds step's line and file say how a scheme fell back; the results page says
    it from the scores; a scene that stratifies by node writes no note."""
    skin = Skin(4, 4)
    frame = row_column_dataset(skin, [1, 2, 3, 4], [1, 2, 3, 4])
    features = tmp_path / "features.parquet"
    write_dataset(frame, "single_force", features, {"kind": "single_force"}, skin=skin)
    said = folds_at(features, tmp_path / "paper.parquet", scene="lab",
                    schemes=["stratified", "conditions"], n_splits=7, seed=1)
    assert said == "lab: 7 folds of 280 rows, 70 trials, for stratified, conditions CV"
    assert read_fold_notes(tmp_path / "paper.parquet") == {}
    once = frame.groupby("trial").head(1)  # 4 rows a node, 6 at rest: fewer than 7 folds
    write_dataset(once, "single_force", features, {"kind": "single_force"}, skin=skin)
    said = folds_at(features, tmp_path / "once.parquet", scene="lab",
                    schemes=["stratified", "conditions"], n_splits=7, seed=1)
    notes = read_fold_notes(tmp_path / "once.parquet")
    assert set(notes) == {"stratified", "conditions"}
    assert said.endswith(f"; stratified and conditions CV {notes['stratified']}")
    scores = {"force": {"status": "skipped", "reason": "why", "fold_notes": notes}}
    assert (f"- lab conditions CV folds: {notes['conditions']}"
            in page.results_markdown([("lab", "single_force", skin, scores)]))


def test_training_on_fallen_back_folds_keeps_their_note_in_its_scores(params, tmp_path):
    """The scores file and the training's line carry the folds step's note."""
    skin = Skin(4, 4)
    once = row_column_dataset(skin, [1, 2, 3, 4], [1, 2, 3, 4]).groupby("trial").head(1)
    write_dataset(once, "single_force", tmp_path / processed_path("lab"),
                  {"kind": "single_force", "scene": "lab",
                   "source": {"kind": "import", "path": "lab.csv", "sha256": "0" * 64}},
                  skin=skin)
    featurize_at("lab", tmp_path / "data/processed", tmp_path / "data/features",
                 tmp_path / "models", settings=params.featurize)
    folds_at(tmp_path / features_path("lab"), tmp_path / folds_path("lab"),
             schemes=["stratified", "conditions"], n_splits=7, seed=1, scene="lab")
    notes = read_fold_notes(tmp_path / folds_path("lab"))
    done = train_at("lab", "stretch", task_params=params.train.stretch,
                       configuration=params.train.configuration, cv=params.cv,
                       features_dir=tmp_path / "data/features",
                       **{name: tmp_path / path
                          for name, path in task_outputs("lab", "stretch").items()})
    scores = json.loads((tmp_path / task_outputs("lab", "stretch")["scores_path"]).read_text())
    assert scores["fold_notes"] == notes and set(notes) == {"stratified", "conditions"}
    assert f"\n  note (conditions folds): {notes['conditions']}" in done.summary
