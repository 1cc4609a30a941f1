"""Two contacts under one force sensor (issue 37): a recording that gives only their total
force trains that total and the pair of positions, from ingest to the ONNX stack, and says
plainly, once, that it cannot give per-contact forces."""

from __future__ import annotations

import copy
import json

import numpy as np
import onnx
import pandas as pd
import pytest
import yaml
from conftest import acquire_step, headless_chromium, ingest_step, needs_chromium, typed
from foreign_tactile import CHANNELS, GRID_MM, write_two_touch_recording

from eskin.catalog import (
    METRICS,
    PAIRS,
    PAIRS_DIR,
    TASK_NAMES,
    features_path,
    featurizer_path,
    folds_path,
    model_path,
    predictions_path,
    processed_path,
    scores_path,
    stack_path,
    task_outputs,
)
from eskin.config.report import Report
from eskin.config.scenes import scene_kind
from eskin.data.schema import (
    DatasetError,
    contact_mask,
    dataset_kind,
    md5_file,
    read_metadata,
    validate,
    write_dataset,
)
from eskin.deploy.stack import ExportedStack, SkinStack
from eskin.deploy.view import LiveView
from eskin.evaluation.pairs import score_pairs, score_scene_pairs
from eskin.evaluation.tasks import get_task
from eskin.kinds import (
    TOTAL_FORCE_ONLY,
    TWO_CONTACTS,
    TWO_CONTACTS_TOTAL_FORCE,
    get_kind,
    kind_of_labels,
)
from eskin.reporting import report
from eskin.skin import skin_from_dict
from eskin.steps.export import export_at
from eskin.steps.featurize import featurize_at
from eskin.steps.folds import folds_at
from eskin.steps.train import train_at

SKIN = {"channels": CHANNELS, "x_mm": list(GRID_MM), "y_mm": list(GRID_MM)}
TOTAL_LABELS = ["force", "x1", "y1", "x2", "y2", "stretch"]


def two_touch_scene(folder) -> dict:
    return {"kind": "two_force", "source": "import", "skin": SKIN,
            "import": {"path": str(folder),
                       "columns": {"force": "Fz", "time": "timestamp"},
                       "position_from_name": r"x(?P<x1_mm>[\d.]+)_y(?P<y1_mm>[\d.]+)_"
                                             r"x(?P<x2_mm>[\d.]+)_y(?P<y2_mm>[\d.]+)",
                       "force_sign": -1, "contact_n": 0.5, "trials": "file"}}


# every test reads a two-contact pipeline run here, in process (acquisition to report)
pytestmark = pytest.mark.heavy

@pytest.fixture(scope="module")
def pipeline(tmp_path_factory, repo_params):
    """ingest → featurize → every task → pairs → export → report, as the stages run them,
    on three folds in this process."""
    root = tmp_path_factory.mktemp("total")
    write_two_touch_recording(root / "files")
    params = copy.deepcopy(repo_params)
    params["scenes"] = {"two": two_touch_scene(root / "files")}
    params["ingest"]["bad_rows"] = "quarantine"
    params["cv"].update(folds=3, n_jobs=1, backend="sequential")
    # the row/column models' generic stand-ins on a channel array, lighter
    params["train"]["force"]["hist_gradient_boosting"]["max_iter"] = 30
    params["train"]["localise"]["hist_gradient_boosting"] = {"max_iter": 20}
    params = typed(params)
    acquire_step(params, "two", root / "data/raw/two")
    ingested = ingest_step(params, "two", root / "data/raw/two", root / "data/processed")
    featurize_at("two", root / "data/processed", root / "data/features", root / "models",
                 settings=params.featurize)
    folds_at(root / features_path("two"), root / folds_path("two"),
             schemes=list(params.cv.schemes), n_splits=int(params.cv.folds),
             seed=int(params.cv.seed), scene="two")
    trained = {task: train_at(
        "two", task, task_params=getattr(params.train, task),
        configuration=params.train.configuration, cv=params.cv,
        features_dir=root / "data/features",
        **{name: root / path for name, path in task_outputs("two", task).items()})
        for task in TASK_NAMES}
    outs = [featurizer_path("two"), *(model_path("two", task) for task in TASK_NAMES)]
    # dvc.lock as DVC records the outputs the stack is loaded from (their md5s)
    (root / "dvc.lock").write_text(yaml.safe_dump({"stages": {"train": {"outs": [
        {"path": path.as_posix(), "md5": md5_file(root / path)} for path in outs]}}}))
    exported = export_at("two", root)
    report.report(
        report=Report(schemes=["stratified", "conditions"], plots_scheme="stratified", dpi=40,
                      page_dpi=30),
        scenes=params.scenes, scores_dir=root / "reports/scores",
        predictions_dir=root / "reports/predictions", figures_dir=root / "reports/figures",
        plots_dir=root / "reports/plots", page_path=root / "reports/index.html",
        results_path=root / "reports/results.md",
        metrics_path=root / METRICS, pairs_dir=root / PAIRS_DIR)
    scores = {task: json.loads((root / scores_path("two", task)).read_text())
              for task in (*TASK_NAMES, PAIRS)}
    paired = score_scene_pairs("two", {task: pd.read_parquet(root / predictions_path("two", task))
                                       for task in ("localise", "force")}, scores["localise"])
    return {"root": root, "params": params, "ingested": ingested, "trained": trained,
            "paired": paired, "exported": exported, "scores": scores}


def test_the_dataset_and_its_features_are_of_the_total_force_kind(pipeline):
    root = pipeline["root"]
    assert scene_kind(pipeline["params"].scenes["two"]) is TWO_CONTACTS_TOTAL_FORCE
    for path in (processed_path("two"), features_path("two")):
        assert dataset_kind(root / path) is TWO_CONTACTS_TOTAL_FORCE
        assert read_metadata(root / path)["labels"] == TOTAL_LABELS
        assert read_metadata(root / path)["kind"] == "two_force"  # the scene's, as declared
    features = pd.read_parquet(root / features_path("two"))
    assert "force1" not in features and list(features.columns[15:21]) == TOTAL_LABELS


def test_the_total_force_is_trained_and_scored_as_a_regression(pipeline):
    force = pipeline["scores"]["force"]
    assert force["status"] == "trained" and force["kind"] == "two_force_total"
    for scheme in ("stratified", "conditions"):
        assert set(force[scheme]) == {"force"}
        assert np.isfinite(force[scheme]["force"]["r2"]) and force[scheme]["force"]["rmse"] > 0
    # conditions CV holds out whole files, each a pair of places never seen in training
    assert force["stratified"]["force"]["r2"] > 0.9
    oof = pd.read_parquet(pipeline["root"] / task_outputs("two", "force")["predictions_path"])
    assert {"force_true", "force_pred"} <= set(oof.columns)
    assert "force1_true" not in oof


def test_the_positions_are_trained_and_scored_and_the_rest_skipped_with_reasons(pipeline):
    scores = pipeline["scores"]
    localise = scores["localise"]
    assert localise["status"] == "trained"
    for scheme in ("stratified", "conditions"):
        assert {"x1", "y1", "x2", "y2", "position1", "position2"} <= set(localise[scheme])
    stratified = localise["stratified"]
    assert min(stratified[t]["accuracy"] for t in ("x1", "y1", "x2", "y2")) > 0.9
    assert stratified["position1"]["error_mm"] < 1.0
    assert scores["stretch"]["status"] == "skipped"
    assert "two or more stretch levels" in scores["stretch"]["reason"]
    assert scores["detect"]["status"] == "skipped"
    assert "every sample of this scene has 2" in scores["detect"]["reason"]


def test_pairs_score_the_positions_and_skip_the_per_contact_forces_with_the_reason(pipeline):
    pairs, paired = pipeline["scores"][PAIRS], pipeline["paired"]
    assert pairs["status"] == "scored"
    assert pairs["skipped_scores"] == {"force": TOTAL_FORCE_ONLY}
    for scheme in ("stratified", "conditions"):
        assert 0 < pairs[scheme]["pair_accuracy"] <= 1
        assert not any(name.startswith("force") for name in pairs[scheme])
    assert pairs["stratified"]["pair_accuracy"] > 0.9
    assert paired.summary.count(TOTAL_FORCE_ONLY) == 1
    metrics = json.loads((pipeline["root"] / METRICS).read_text())
    assert set(metrics["two"]["pairs"]) == {"pair_accuracy", "ghost_share"}


def test_the_report_gives_the_total_force_and_says_once_why_there_is_no_per_contact_force(
        pipeline):
    root = pipeline["root"]
    results = (root / "reports/results.md").read_text()
    assert "## two (two force, total force only)" in results
    assert "| two contacts: total force R² [hist_gradient_boosting] |" in results
    assert "two contacts: pair accuracy, order-free" in results
    assert "force 1" not in results and "force R², order-free" not in results
    assert results.count(TOTAL_FORCE_ONLY) == 1
    assert f"- two/pairs force scores skipped: {TOTAL_FORCE_ONLY}" in results
    page = (root / "reports/index.html").read_text()
    assert page.count(TOTAL_FORCE_ONLY) == 1
    figures = root / "reports/figures/two"
    assert {p.name for p in figures.glob("*.png")} == {
        f"{figure}_{scheme}.png" for figure in ("force_parity", "localisation_confusion")
        for scheme in ("stratified", "conditions")}
    parity = pd.read_csv(root / "reports/plots/parity/two_force.csv")
    assert list(parity.columns) == ["actual", "predicted", "panel"]


def test_the_stack_outputs_the_total_force_and_the_pair_of_positions(pipeline):
    root = pipeline["root"]
    path = root / stack_path("two")
    model = onnx.load(path)
    outputs = [output.name for output in model.graph.output]
    assert outputs == ["stretch", "x1", "y1", "x2", "y2", "force"]
    assert outputs == TWO_CONTACTS_TOTAL_FORCE.stack_outputs(counted=False)
    props = {p.key: p.value for p in model.metadata_props}
    assert props["eskin.kind"] == "two_force_total"
    assert json.loads(props["eskin.columns"]) == outputs
    exported, workspace = ExportedStack.from_file(path), SkinStack.from_workspace("two", root)
    assert exported.skin == workspace.skin == skin_from_dict(SKIN)
    frames = pd.read_parquet(root / processed_path("two"))
    counts = frames[CHANNELS].to_numpy()[:200]
    estimates = exported.predict(counts)
    pd.testing.assert_frame_equal(estimates, workspace.predict(counts), rtol=1e-9)
    truth = frames["force"].to_numpy()[:200]
    assert np.corrcoef(estimates["force"], truth)[0, 1] > 0.8
    assert estimates["stretch"].isna().all()  # no stretch model: one stretch recorded


# ---------------------------------------------------------------- the parts

def test_a_kind_knows_its_total_force_variant():
    total = TWO_CONTACTS.with_total_force()
    assert total is TWO_CONTACTS_TOTAL_FORCE and total.total_force
    assert total.scene_kind == "two_force" and total.contacts == 2
    assert total.detect_target == "contacts"
    assert total.labels == TOTAL_LABELS
    assert total.force_columns == ["force"] and total.node_columns == ["x1", "y1", "x2", "y2"]
    assert total.weighed_contacts == {"force": ["x1", "x2"]}
    assert set(get_task(total.name, "force").targets) == {"force"}
    assert get_task(total.name, "localise").positions == {"position1": ("x1", "y1"),
                                                          "position2": ("x2", "y2")}
    assert get_kind(total.name) is total
    with pytest.raises(ValueError, match="single_force scene has no total-force variant"):
        get_kind("single_force").with_total_force()


def test_a_dataset_kind_is_read_from_its_labels():
    assert kind_of_labels("two_force", None) is TWO_CONTACTS
    assert kind_of_labels("two_force", TWO_CONTACTS.labels) is TWO_CONTACTS
    assert kind_of_labels("two_force", TOTAL_LABELS) is TWO_CONTACTS_TOTAL_FORCE
    with pytest.raises(ValueError, match=r"labels force, x1, stretch are not those of a "
                                         r"two_force dataset \(force1, x1"):
        kind_of_labels("two_force", ["force", "x1", "stretch"])


def total_frame() -> pd.DataFrame:
    skin = skin_from_dict(SKIN)
    frame = pd.DataFrame(np.ones((3, skin.terminals)), columns=skin.channels)
    return frame.assign(force=[1.0, 2.0, 3.0], x1=[1, 1, 2], y1=[1, 2, 2], x2=[3, 3, 3],
                        y2=[3, 2, 1], stretch=1.0, session="s", trial="t", sample=[0, 1, 2],
                        seq=[0, 1, 2], t_ms=[0, 10, 20])


def test_the_schema_takes_the_total_force_labels_and_records_them(tmp_path):
    skin, frame = skin_from_dict(SKIN), total_frame()
    validate(frame, TWO_CONTACTS_TOTAL_FORCE.name, skin=skin)
    with pytest.raises(DatasetError, match="missing column"):
        validate(frame, TWO_CONTACTS.name, skin=skin)
    with pytest.raises(DatasetError, match="first at row 1: force is negative"):
        validate(frame.assign(force=[1.0, -1.0, 2.0]), TWO_CONTACTS_TOTAL_FORCE.name, skin=skin)
    path = tmp_path / "total.parquet"
    write_dataset(frame, TWO_CONTACTS_TOTAL_FORCE.name, path, {"kind": "two_force"}, skin=skin)
    assert read_metadata(path)["labels"] == TOTAL_LABELS
    assert dataset_kind(path) is TWO_CONTACTS_TOTAL_FORCE
    assert contact_mask(frame).all() and not contact_mask(frame.assign(force=0.0)).any()


def test_pairs_without_per_contact_forces_score_the_positions_only():
    localise = pd.DataFrame({"scheme": "conditions", "trial": ["a", "b"], "sample": 0,
                             "fold": [0, 1], "x1_true": [1, 1], "y1_true": [1, 1],
                             "x2_true": [2, 2], "y2_true": [2, 2], "x1_pred": [2, 1],
                             "y1_pred": [2, 1], "x2_pred": [1, 3], "y2_pred": [1, 3]})
    scores = score_pairs(localise, None)["conditions"]
    assert scores["pair_accuracy"] == 0.5 and scores["pair_accuracy_ordered"] == 0.0
    assert not any(name.startswith("force") for name in scores)


@needs_chromium
@pytest.mark.starts
def test_the_live_view_shows_the_total_force_and_both_places():
    skin = skin_from_dict(SKIN)
    estimate = {"seq": 7, "t_ms": 70, "stretch": 1.0, "x1": 1, "y1": 1, "x2": 3, "y2": 3,
                "force": 4.25, "drift_counts": 0.0, "change_counts": [0.0] * skin.terminals}
    with LiveView(scene="two", kind="two_force_total", device="lab", skin=skin) as view:
        view.show(estimate)
        with headless_chromium() as browser:
            page = browser.new_page()
            page.goto(view.url)
            page.wait_for_function(
                "document.getElementById('location').textContent !== '–'", timeout=30_000)
            shown = {name: page.inner_text(f"#{name}") for name in ("location", "force")}
            marked = [page.eval_on_selector(f"#cell-{x}-{y}", "c => c.style.background")
                      for x, y in ((1, 1), (3, 3), (2, 2))]
    assert shown["location"] == "x 1, y 1; x 3, y 3"
    assert shown["force"] == ("4.25 N in all (the training recording gave no force per "
                              "contact)")
    assert marked[0] and marked[1] and not marked[2]
