"""The pipeline under real DVC and a real MLflow server: `dvc repro`, `dvc exp run -S`,
`dvc exp run --queue` + `dvc queue start -j 2`, `dvc metrics show`, `eskin compare`,
`eskin audit`, `eskin reproduce`.

A scratch copy of the project (small scenes) runs the real stages; MLflow logs
to an `mlflow server` on 127.0.0.1 (SQLite backend in a temporary directory)
through MLFLOW_TRACKING_URI, and the tests read the runs back through its client.
"""

import json
import re
import subprocess
import sys
import time

import pandas as pd
import pytest
import yaml
from conftest import (
    ROOT,
    copy_small_pipeline,
    headless_chromium,
    needs_chromium,
    params_trace_dir,
    run_checked,
)
from test_stage_deps import params_mismatches

from eskin.config.train import TaskModels
from eskin.data.schema import md5_file
from eskin.learning.choice import model_settings
from eskin.skin import PAPER_SKIN

# Each test here starts a pipeline or a server: `make check` leaves them out.
pytestmark = pytest.mark.starts


def run(args, cwd, env):
    return run_checked(args, cwd, env).stdout


@pytest.fixture(scope="module")
def scratch(tmp_path_factory, small_pipeline, lab):
    root = tmp_path_factory.mktemp("pipeline")
    env = copy_small_pipeline(small_pipeline, root, lab[1].uri)  # the lab's, on PostgreSQL
    assert run(["git", "status", "--porcelain"], root, env) == "", "the repro is committed"
    return root, env


@needs_chromium
def test_the_link_the_tracking_stage_prints_shows_the_headline_scores(scratch):
    """The link `dvc repro`'s publish stage prints opens MLflow's runs table (on the real
    server) with each headline score as a column named with its CV scheme, and the
    variants newest first. First in the module: the publish stage, run again on the
    workspace as the fixture left it, logs nothing new (a later test's `dvc exp run`
    leaves the workspace on the experiment's params, which a plain repro would log as a
    variant of its own)."""
    import mlflow

    from eskin.tracking import runs

    root, env = scratch
    mlflow.set_tracking_uri(env["MLFLOW_TRACKING_URI"])
    before = len(mlflow.search_runs(experiment_names=["eskin"],
                                    filter_string="tags.`eskin.kind` = 'task'"))
    printed = run(["dvc", "repro", "--force", "--single-item", "publish"], root, env)
    link = next(word for word in printed.split() if word.startswith("http"))
    assert "viewStateShareKey=" in link, printed
    written = json.loads((root / "reports" / "metrics.json").read_text())
    score = written["single_force"]["force"]["r2"]
    with headless_chromium() as browser:
        page = browser.new_page(viewport={"width": 1600, "height": 1000})
        page.goto(link)
        page.wait_for_selector("text=conditions.single_force.force.r2", timeout=60_000)
        headers = page.eval_on_selector_all(
            ".ag-header-cell[col-id]", "cells => cells.map(c => c.getAttribute('col-id'))")
        page.wait_for_selector(f"text={str(score)[:7]}", timeout=30_000)  # its value
        state = page.url
    # the columns on screen (the grid draws only those), then the view's every column
    assert "metrics.`conditions.single_force.force.r2`" in headers, headers
    client = mlflow.MlflowClient()
    view = json.loads(client.get_experiment_by_name("eskin").tags[
        runs.SHARED_VIEW_TAG + runs.HEADLINE_VIEW])
    assert {f"metrics.`{name}`" for name in runs.headline_metrics(written)} <= set(
        view["selectedColumns"]), view
    assert len(mlflow.search_runs(experiment_names=["eskin"],
                                  filter_string="tags.`eskin.kind` = 'task'")) == before
    assert "orderByKey=attributes.start_time&orderByAsc=false" in state, state  # newest first


def test_each_stage_reads_exactly_the_params_it_declares(scratch):
    root, _ = scratch
    assert params_mismatches(root, params_trace_dir(root)) == []


def test_dvc_metrics_show_lists_the_headline_metrics(scratch):
    root, env = scratch
    shown = json.loads(run(["dvc", "metrics", "show", "--json"], root, env))
    files = {path: content["data"] for data in shown.values()
             for path, content in data["data"].items() if "data" in content}
    # A file a scene: the headline only (conditions CV, one number a question; every
    # scheme, spread and confusion count is in reports/scores/, every target's headline in
    # reports/metrics.json).
    assert sorted(files) == ["reports/metrics/single_force.json",
                             "reports/metrics/two_force.json"]
    one = files["reports/metrics/single_force.json"]
    scores = json.loads((root / "reports/scores/single_force/stretch.json").read_text())
    assert one["stretch"] == scores["conditions"]["stretch"]["r2"]
    assert set(one) == {"stretch", "force", "contact", "x", "y"}  # no pairs: one contact
    # the default two_force scene counts its contacts (contact_counts): the count's too
    assert set(files["reports/metrics/two_force.json"]) == {"contacts", "pairs", "pair_force"}
    headline = json.loads((root / "reports/metrics.json").read_text())
    assert set(headline["two_force"]) == {"detect", "force", "localise", "pairs"}
    assert set(headline["two_force"]["pairs"]) == {"pair_accuracy", "ghost_share", "force_r2"}
    table = run_checked(["dvc", "metrics", "show"], root, {**env, "COLUMNS": "120"}).stdout
    assert "pair_force" in table and "contact" in table
    assert "stratified" not in table and "_std" not in table


def test_a_second_force_model_is_a_second_mlflow_run_on_the_same_dataset(scratch, repo_params):
    root, env = scratch
    out = run(["dvc", "exp", "run", "-n", "force-rf", "-S",
               "train.force.model.single_force=random_forest"], root, env)
    assert "Running stage 'train@single_force'" in out
    for task in ("stretch", "detect", "localise"):  # only what changed is trained
        assert f"single_force/{task}: kept" in out, out
    # nor the other kind's scene, which shares train.force (its settings did not change)
    assert "Running stage 'train@two_force'" not in out

    import mlflow
    mlflow.set_tracking_uri(env["MLFLOW_TRACKING_URI"])
    runs = mlflow.search_runs(experiment_names=["eskin"],
                              filter_string="tags.`eskin.task` = 'force' and "
                                            "tags.`eskin.scene` = 'single_force'")
    default, _ = model_settings(TaskModels.model_validate(repo_params["train"]["force"]),
                                "tuned", "single_force")
    # Hyperparameters under stable names (force.<name>), whichever model ran.
    assert sorted(runs["params.force.model"]) == sorted([default, "random_forest"])
    digest = md5_file(root / "data" / "processed" / "single_force.parquet")
    assert set(runs["tags.eskin.dataset_digest"]) == {digest}
    experiment_run = runs[runs["params.force.model"] == "random_forest"].iloc[0]
    assert experiment_run["tags.eskin.dvc_experiment"] == "force-rf"
    assert experiment_run["params.force.n_estimators"] == "100"

    client = mlflow.MlflowClient()
    for run_id in runs["run_id"]:
        run_ = client.get_run(run_id)
        inputs = run_.inputs.dataset_inputs
        assert [i.dataset.digest for i in inputs] == [digest]
        assert run_.data.tags["mlflow.parentRunId"]
        assert run_.data.tags["eskin.git_commit"]
        assert "stratified.force.r2" in run_.data.metrics
    # The daily loop's view of the two (docs/experiments.md), in a 120-column terminal:
    # every changed score and the changed param, no dependency's hash.
    changed = run(["dvc", "exp", "show", "--only-changed", "--csv"], root, env)
    changed_scores = [c for c in changed.splitlines()[0].split(",") if c == "force"]
    assert changed_scores, changed  # DVC's single-force force score (reports/metrics/)
    shown = run_checked(["dvc", "exp", "show", "--only-changed", "--drop", "Created|models|.*/",
                         "--no-pager"], root, {**env, "COLUMNS": "120"}).stdout
    assert max(len(line) for line in shown.splitlines()) <= 120, shown
    for column in (*changed_scores, "train.force.model.single_force", "random_forest",
                   "physics_profile", "force-rf"):
        assert column in shown, (column, shown)
    # The dataset version DVC records is the digest MLflow carries.
    lock = yaml.safe_load((root / "dvc.lock").read_text())
    outs = lock["stages"]["prepare@single_force"]["outs"]
    assert digest in {o["md5"] for o in outs}


def test_the_report_stage_writes_the_results_page_and_dvc_plots_render(scratch):
    root, env = scratch
    results = (root / "reports" / "results.md").read_text()
    assert "| stretch R² [paper] | 0." in results
    # The README is prose, not an output: editing it leaves the pipeline up to date.
    readme = root / "README.md"
    prose = readme.read_text()
    readme.write_text(prose + "\nA sentence a user added.\n")
    try:
        assert "Data and pipelines are up to date." in run(["dvc", "status", "dvc.yaml"],
                                                           root, env)
    finally:
        readme.write_text(prose)
    assert (root / "reports" / "index.html").stat().st_size > 10_000


def test_after_a_repro_dvc_status_and_checkout_are_clean_and_quiet(scratch):
    """A clone after `make repro`: DVC's cache holds the pipeline's outputs, not the bench's,
    though bench/dvc.lock names them (the bounds only `make bench` makes). bench/ and
    stress/ are DVC projects of their own, so the project's `dvc status` and `dvc checkout`
    say nothing of them; in bench/, its status says what is missing."""
    root, env = scratch
    lock = root / "bench" / "dvc.lock"
    lock.write_text((ROOT / "bench" / "dvc.lock").read_text())
    try:
        status = run_checked(["dvc", "status"], root, env)
        assert status.stdout.strip() == "Data and pipelines are up to date.", status.stdout
        checkout = run_checked(["dvc", "checkout"], root, env)
        assert (checkout.stdout + checkout.stderr).strip() == "", checkout
        assert "changed outs" in run_checked(["dvc", "status"], root / "bench", env).stdout
    finally:
        lock.unlink()



@needs_chromium
def test_dvc_plots_draw_offline_in_headless_chromium(scratch):
    """`dvc plots show` (and so `dvc plots diff`) writes a page that draws with no network:
    vega is in the page template `make setup` writes; each panel is titled with its
    scene and target, parity panels have the ideal line, classes are in numeric order."""
    root, env = scratch
    run(["dvc", "plots", "show", "-o", str(root / "dvc_plots")], root, env)
    page_path = root / "dvc_plots" / "index.html"
    assert "dvc_plots" not in run(["git", "status", "--porcelain"], root, env)  # ignored
    requested, errors = [], []
    with headless_chromium() as browser:
        context = browser.new_context(offline=True)
        page = context.new_page()
        page.on("request", lambda request: requested.append(request.url))
        page.on("pageerror", lambda error: errors.append(str(error)))
        page.goto(page_path.as_uri())
        plots = page.eval_on_selector_all(".vega-embed", "e => e.length")
        page.wait_for_function(
            f"document.querySelectorAll('.vega-embed svg.marks').length == {plots}",
            timeout=60_000)
        panels = page.eval_on_selector_all("g.role-title-text text",
                                           "ts => ts.map(t => t.textContent)")
        points = page.eval_on_selector_all("g.mark-symbol path", "ps => ps.length")
        ideal = page.eval_on_selector_all("g.mark-line path", "ps => ps.length")
        cells = page.eval_on_selector_all("g.mark-rect path", "ps => ps.length")
        # the x axis of the single-force x-terminal confusion matrix, left to right
        x_axis = page.evaluate("""() => {
            const svg = [...document.querySelectorAll('.vega-embed svg')].find(
                s => s.textContent.includes('single_force: x terminal'));
            const axis = svg.querySelector('g.role-axis[aria-label^="X-axis"]');
            return [...axis.querySelectorAll('g.role-axis-label text')].map(t => t.textContent);
        }""")
    assert not errors, errors
    assert [url for url in requested if not url.startswith("file:")] == []
    # 4 parity panels, 8 confusion matrices (small scenes; two_force counts its contacts)
    assert plots == 12, plots
    for panel in ("single_force: stretch λ", "single_force: force (N)",
                  "two_force: force of contact 2 (N)", "single_force: contact",
                  "two_force: y terminal of contact 1"):
        assert panel in panels, (panel, panels)
    assert points > 500 and ideal == 4 and cells > 20, (points, ideal, cells)
    assert x_axis == [str(n) for n in range(1, 11)], x_axis


@needs_chromium
def test_the_mlflow_ui_opens_on_the_training_runs_and_shows_their_figures(scratch,
                                                                          monkeypatch):
    """The links eskin prints (the publish stage's, `make lab-server`'s), opened in headless
    Chromium on the real server: MLflow 3's UI shows the training view (it picks the view
    from the URL, else the browser's last choice, GenAI by default), run names say scene,
    task, model and variant, the duration is the training's, the figures are artifacts."""
    import mlflow

    from eskin.tracking import connection


    root, env = scratch
    monkeypatch.setenv("MLFLOW_TRACKING_URI", env["MLFLOW_TRACKING_URI"])
    mlflow.set_tracking_uri(env["MLFLOW_TRACKING_URI"])
    experiment = mlflow.MlflowClient().get_experiment_by_name("eskin").experiment_id
    task = mlflow.search_runs(experiment_names=["eskin"], filter_string=(
        "tags.`eskin.task` = 'force' and tags.`eskin.scene` = 'single_force' and "
        "tags.`eskin.dvc_experiment` = ''")).iloc[0]
    parent = mlflow.MlflowClient().get_run(task["tags.mlflow.parentRunId"])
    with headless_chromium() as browser:
        page = browser.new_page(viewport={"width": 1600, "height": 1000})

        def text_of(url: str, wait_for: str) -> str:
            # A whole load each time: the links differ only after '#', and the UI, moved
            # between two runs' artifact tabs in place, keeps showing the first run's list.
            page.goto("about:blank")
            page.goto(url)
            page.wait_for_selector(f"text={wait_for}", timeout=60_000)
            return page.inner_text("body")

        listing = text_of(connection.ui_url(experiment), parent.info.run_name)
        assert "/runs" in page.url and "Duration" in listing and "Token Usage" not in listing
        run_page = text_of(connection.ui_url(experiment, task["run_id"]), "Duration")
        artifacts = text_of(connection.ui_url(experiment, task["run_id"], artifacts=True),
                            "figures")
        page_artifacts = text_of(connection.ui_url(experiment, parent.info.run_id, artifacts=True),
                                 "index.html")
    assert task["tags.mlflow.runName"] in run_page  # single_force/force <model> @repro-…
    shown = run_page.split("Duration", 1)[1].split()[0]  # "26.9s", "1.2min"
    seconds = (task["end_time"] - task["start_time"]).total_seconds()
    assert shown.endswith(("s", "min")) and not shown.endswith("ms"), shown
    assert float(shown.rstrip("mins")) * (60 if shown.endswith("min") else 1) == \
        pytest.approx(seconds, rel=0.1, abs=0.1), (shown, seconds)
    assert "index.html" in page_artifacts and "figures" in artifacts


def test_a_repro_groups_its_task_runs_under_one_pipeline_run(scratch):
    root, env = scratch
    import mlflow
    mlflow.set_tracking_uri(env["MLFLOW_TRACKING_URI"])
    runs = mlflow.search_runs(experiment_names=["eskin"],
                              filter_string="tags.`eskin.kind` = 'task' and "
                                            "tags.`eskin.dvc_experiment` = ''")
    # Four single-force tasks; two-force detect (it counts), force and localise (stretch
    # skips: one stretch level).
    assert sorted(runs["tags.eskin.scene"] + "/" + runs["tags.eskin.task"]) == [
        *(f"single_force/{t}" for t in ("detect", "force", "localise", "stretch")),
        "two_force/detect", "two_force/force", "two_force/localise"]
    assert runs["tags.mlflow.parentRunId"].nunique() == 1
    # The UI: the training view, runs named by scene, task, model and variant, and
    # durations that are the training's (the run starts when the step did).
    experiment = mlflow.MlflowClient().get_experiment_by_name("eskin")
    assert experiment.tags["mlflow.experimentKind"] == "custom_model_development"
    parent = mlflow.MlflowClient().get_run(runs["tags.mlflow.parentRunId"].iloc[0])
    for _, task_run in runs.iterrows():
        assert task_run["tags.mlflow.runName"] == (
            f"{task_run['tags.eskin.scene']}/{task_run['tags.eskin.task']} "
            f"{task_run['tags.eskin.model']} @{parent.info.run_name}")
    assert parent.info.run_name.startswith("repro-")
    seconds = (runs["end_time"] - runs["start_time"]).dt.total_seconds()
    assert (seconds >= runs["metrics.wall_seconds"] - 0.01).all()
    assert parent.info.end_time >= runs["end_time"].max().timestamp() * 1000 - 1
    # Artifacts go through the server: predictions and models come back from it.
    run_id = runs[(runs["tags.eskin.task"] == "detect")
                  & (runs["tags.eskin.scene"] == "single_force")].iloc[0]["run_id"]
    listed = {a.path for a in mlflow.MlflowClient().list_artifacts(run_id, "predictions")}
    assert listed == {"predictions/oof_stratified.parquet", "predictions/oof_conditions.parquet"}
    # A run's headline metric is the mean over folds, as in the metrics file; the
    # folds are a history of their own.
    logged = mlflow.MlflowClient().get_run(run_id).data.metrics
    written = json.loads((root / "reports" / "metrics.json").read_text())
    assert logged["conditions.contact.accuracy"] == written["single_force"]["detect"]["contact"][
        "accuracy"]
    per_fold = mlflow.artifacts.load_dict(f"runs:/{run_id}/scores/per_fold_conditions.json")
    assert len(per_fold["contact"]) == 3
    assert "conditions.fold.contact.accuracy" not in logged
    model = mlflow.sklearn.load_model(f"runs:/{run_id}/detect-contact")
    features = pd.read_parquet(root / "data" / "features" / "single_force.parquet")
    assert set(model.predict(features[PAPER_SKIN.channels].head(50))) <= {False, True}
    # The pipeline run carries the params the pipeline reads (for `eskin compare`), not
    # make bench's, and the headline scores; its tags name every scene.
    parent = mlflow.MlflowClient().get_run(runs.iloc[0]["tags.mlflow.parentRunId"])
    assert parent.data.params["sim.seed"] == str(yaml.safe_load(
        (root / "params.yaml").read_text())["sim"]["seed"])
    assert not [k for k in parent.data.params if k.split(".")[0] in ("bench", "stress", "soak",
                                                                      "fuzz")]
    assert parent.data.metrics["conditions.single_force.detect.contact.accuracy"] == logged[
        "conditions.contact.accuracy"]
    assert parent.data.tags["eskin.scenes"] == "single_force,two_force"
    assert "eskin.scene" not in parent.data.tags
    # Each task run holds its own figures, and the pipeline run the page (through the server).
    client = mlflow.MlflowClient()
    logged = {a.path for a in client.list_artifacts(run_id, "figures")}
    written = {f"figures/{p.name}"
               for p in (root / "reports" / "figures" / "single_force").glob("detection_*")}
    assert logged == written and any(p.endswith(".png") for p in logged), logged
    assert "index.html" in {a.path for a in client.list_artifacts(parent.info.run_id)}
    # A registered version says what it is: dataset, scores, run.
    version = client.get_model_version("single_force.detect.contact", "1")
    assert run_id in version.description and "conditions CV: contact accuracy" in \
        version.description and "rows" in version.description


def test_eskin_live_runs_the_reproduced_stack_and_refuses_a_changed_model_file(scratch):
    """The stack `dvc repro` trained, on the simulated board's stream; every file of it
    checked against dvc.lock first."""
    root, env = scratch
    done = eskin_cli(["live", "single_force", "--simulated", "--frames", "5",
                      "--tare-frames", "10"], root, env)
    records = [json.loads(line) for line in done.stdout.splitlines()]
    assert "tare" in records[0] and [r["seq"] for r in records[1:]] == list(range(10, 15))
    assert all(r["contact"] is False and r["force"] == 0.0 for r in records[1:])
    # dvc repro exported the stack, and found it agreeing with the scikit-learn stack
    agreement = json.loads((root / "reports" / "export" / "single_force.json").read_text())
    assert agreement["frames"] > 1000
    assert all(e["differing_alone"] == 0 for e in agreement["estimates"].values())
    done = eskin_cli(["live", "single_force", "--simulated", "--onnx", "--frames", "5",
                      "--tare-frames", "10"], root, env)
    exported = [json.loads(line) for line in done.stdout.splitlines()]
    assert [r["seq"] for r in exported[1:]] == list(range(10, 15))
    assert all(r["contact"] is False for r in exported[1:])
    model = root / "models" / "single_force" / "force.joblib"
    original = model.read_bytes()
    try:
        model.write_bytes(original + b"\0")
        done = eskin_cli(["live", "single_force", "--simulated", "--frames", "1"], root, env,
                         check=False)
        assert done.returncode == 1
        assert "models/single_force/force.joblib: md5 is" in done.stderr
        assert "not loading it" in done.stderr and "Traceback" not in done.stderr
    finally:
        model.write_bytes(original)
    # A scene whose kind changed since its stack was trained: retrain, says the one line.
    params = yaml.safe_load((root / "params.yaml").read_text())
    params["scenes"]["single_force"].update(kind="two_force", nodes_x=[1, 10], nodes_y=[1, 10],
                                            forces=[3.2536])
    changed = root / "changed_params.yaml"
    changed.write_text(yaml.safe_dump(params, sort_keys=False))
    try:
        done = eskin_cli(["live", "single_force", "--simulated", "--params", str(changed)],
                         root, env, check=False)
    finally:
        changed.unlink()
    assert done.returncode == 1 and done.stderr.strip().endswith(
        "its trained stack is single_force: run `dvc repro` to train it again")


def test_eskin_live_loads_the_models_registered_under_an_alias(scratch):
    """`--alias champion`: the models registered in MLflow under it, found by the md5 their
    versions recorded; an alias nobody has is one line saying how to set it."""
    from mlflow import MlflowClient

    root, env = scratch
    client = MlflowClient(env["MLFLOW_TRACKING_URI"])
    for task in ("stretch", "force", "detect", "localise"):
        md5 = md5_file(root / "models" / "single_force" / f"{task}.joblib")
        for version in client.search_model_versions(f"name LIKE 'single_force.{task}%'"):
            if version.tags.get("eskin.model_md5") == md5:
                client.set_registered_model_alias(version.name, "champion", version.version)
    done = eskin_cli(["live", "single_force", "--simulated", "--alias", "champion",
                      "--frames", "3", "--tare-frames", "5"], root, env)
    records = [json.loads(line) for line in done.stdout.splitlines()]
    assert [r["seq"] for r in records[1:]] == [5, 6, 7]
    done = eskin_cli(["live", "single_force", "--simulated", "--alias", "nobody"], root, env,
                     check=False)
    assert done.returncode == 1 and "has the alias 'nobody'" in done.stderr


def test_eskin_promote_gives_the_alias_to_a_whole_stack_and_live_loads_it(scratch):
    """`eskin promote`: the alias on every model of one pipeline run's stack of a scene, a
    task DVC reused bringing the versions of the run that trained it, and taken from the
    scene's models outside the stack; `eskin live --alias` then loads exactly those
    versions. A scene, experiment or run that does not exist: one line naming what does."""
    from mlflow import MlflowClient

    root, env = scratch
    client = MlflowClient(env["MLFLOW_TRACKING_URI"])
    experiment = client.get_experiment_by_name("eskin").experiment_id
    pipelines = {run.info.run_name: run for run in client.search_runs(
        [experiment], "tags.`eskin.kind` = 'pipeline'")}
    repro = next(run for name, run in pipelines.items() if name.startswith("repro-"))

    def task_runs(pipeline):
        return {run.data.tags["eskin.task"]: run for run in client.search_runs(
            [experiment], f"tags.`mlflow.parentRunId` = '{pipeline.info.run_id}' and "
                          "tags.`eskin.scene` = 'single_force' and tags.`eskin.kind` = 'task'")}

    def registered_by(run):
        return {v.name: v.version
                for v in client.search_model_versions(f"run_id = '{run.info.run_id}'")}

    def champions():
        return {m.name: m.aliases["champion"]
                for m in client.search_registered_models("name LIKE 'single_force.%'")
                if "champion" in m.aliases}

    repro_runs, rf_runs = task_runs(repro), task_runs(pipelines["force-rf"])
    repro_stack = {name: version for run in repro_runs.values()
                   for name, version in registered_by(run).items()}
    assert set(repro_stack) == {"single_force.stretch", "single_force.force",
                                "single_force.detect.contact", "single_force.localise.x",
                                "single_force.localise.y"}
    # force-rf trained the force model and reused the other three tasks
    assert {t: r.data.tags["eskin.trained"] for t, r in rf_runs.items()} == {
        "stretch": "reused", "force": "here", "detect": "reused", "localise": "reused"}
    rf_force = registered_by(rf_runs["force"])
    assert rf_force["single_force.force"] != repro_stack["single_force.force"]
    # a model of the scene outside any stack, holding the alias: promote takes it away
    client.copy_model_version("models:/single_force.force/1", "single_force.retired")
    client.set_registered_model_alias("single_force.retired", "champion", "1")
    try:
        done = eskin_cli(["promote", "single_force", "--run", repro.info.run_id], root, env)
        assert champions() == repro_stack
        assert "  single_force.retired: alias 'champion' removed (not in this stack)" in \
            done.stdout.splitlines()
        done = eskin_cli(["promote", "single_force", "--experiment", "force-rf"], root, env)
        assert champions() == {**repro_stack, **rf_force}
        header, *lines, footer = done.stdout.splitlines()
        assert pipelines["force-rf"].info.run_id in header and "(force-rf)" in header
        printed = {line.split()[0]: line for line in lines}
        force = printed["single_force.force"]
        assert force.split()[1] == f"v{rf_force['single_force.force']}"
        assert f"run {rf_runs['force'].info.run_id} (trained here)" in force
        assert "conditions CV: force r2 " in force
        assert f"run {repro_runs['stretch'].info.run_id} (reused)" in \
            printed["single_force.stretch"]
        assert len(lines) == len(repro_stack)  # one line per model
        assert footer == "`eskin live single_force --alias champion` runs it"
        # Neither --experiment nor --run: the workspace's stack, which force-rf left.
        done = eskin_cli(["promote", "single_force"], root, env)
        assert "(force-rf)" in done.stdout.splitlines()[0]
        assert champions() == {**repro_stack, **rf_force}
    finally:
        client.delete_registered_model("single_force.retired")
    done = eskin_cli(["live", "single_force", "--simulated", "--alias", "champion",
                      "--frames", "5", "--tare-frames", "5"], root, env)
    assert [json.loads(line)["seq"] for line in done.stdout.splitlines()[1:]] == [5, 6, 7, 8, 9]
    loaded = next(line for line in done.stderr.splitlines() if "registry @champion:" in line)
    assert sorted(loaded.split(": ", 2)[2].split(", ")) == sorted(
        f"{name} v{version}" for name, version in {**repro_stack, **rf_force}.items())

    for args, says in (
            (["nowhere", "--experiment", "force-rf"], "params.yaml has no scene 'nowhere' "
                                                      "(its scenes: single_force, two_force)"),
            (["nowhere"], "params.yaml has no scene 'nowhere' "
                          "(its scenes: single_force, two_force)"),
            (["single_force", "--experiment", "nothing"], "no pipeline run named 'nothing'"),
            (["single_force", "--run", "0" * 32], f"no run {'0' * 32}"),
            (["single_force", "--run", rf_runs["force"].info.run_id],
             f"not a pipeline run: give its pipeline run, --run "
             f"{pipelines['force-rf'].info.run_id}")):
        done = eskin_cli(["promote", *args], root, env, check=False)
        assert done.returncode == 1 and done.stdout == "", (args, done.stdout, done.stderr)
        assert done.stderr.count("\n") == 1 and says in done.stderr, (args, done.stderr)
    assert "force-rf" in eskin_cli(["promote", "single_force", "--experiment", "nothing"],
                                   root, env, check=False).stderr  # names what exists
    assert champions() == {**repro_stack, **rf_force}  # a refusal changes nothing


def eskin_cli(args, root, env, check=True):
    done = subprocess.run([sys.executable, "-m", "eskin", *args], cwd=root, env=env, text=True,
                          capture_output=True, timeout=600)
    if check:
        assert done.returncode == 0, f"eskin {' '.join(args)}:\n{done.stdout}\n{done.stderr}"
    return done


def wait_for_queue(root, env, timeout=600):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        status = run(["dvc", "queue", "status"], root, env)
        if "Queued" not in status and "Running" not in status:
            return status
        time.sleep(3)
    raise AssertionError(f"queue still busy after {timeout} s:\n{status}")


def test_queued_experiments_run_two_at_a_time_and_compare_side_by_side(scratch, tmp_path):
    """Two queued experiments at a time in this clone while a second clone runs one of
    its own: three writers to the lab's server at once, every run landing under its
    experiment's name, on its dataset and commit."""
    root, env = scratch
    # Against the workspace, which the force-rf experiment above left with its params.
    for name, setting in (("q-logistic", "train.detect.model=logistic"),
                          ("q-ridge", "train.stretch.model=ridge")):
        run(["dvc", "exp", "run", "--queue", "-n", name, "-S", setting], root, env)
    second = tmp_path / "second_clone"
    run(["git", "clone", "-q", str(root), str(second)], tmp_path, env)
    run(["dvc", "cache", "dir", str(root / ".dvc" / "cache")], second, env)
    run(["dvc", "checkout", "-q", "dvc.yaml"], second, env)  # not bench/: never run here
    run(["dvc", "queue", "start", "-j", "2"], root, env)
    run(["dvc", "exp", "run", "-n", "c2-alpha", "-S", "train.stretch.ridge.alpha=2.0"],
        second, env)
    status = wait_for_queue(root, env)
    assert status.count("Success") == 2, status

    import mlflow
    mlflow.set_tracking_uri(env["MLFLOW_TRACKING_URI"])
    digest = md5_file(root / "data" / "processed" / "single_force.parquet")
    head = run(["git", "rev-parse", "HEAD"], root, env).strip()
    everything = mlflow.search_runs(experiment_names=["eskin"])
    assert set(everything["status"]) == {"FINISHED"}
    # c2-alpha sets a knob of ridge, which the second clone's stretch task (the paper's
    # linear regression) does not use: its settings file keeps its bytes, nothing retrains
    for name, task in (("q-logistic", "detect"), ("q-ridge", "stretch"), ("c2-alpha", None)):
        logged = mlflow.search_runs(experiment_names=["eskin"], filter_string=(
            f"tags.`eskin.dvc_experiment` = '{name}' and tags.`eskin.kind` = 'task'"))
        found = logged[logged["tags.eskin.trained"] != "reused"]
        # only what the setting changes
        assert set(found["tags.eskin.task"]) == ({task} if task else set()), name
        # every other task is there too, marked reused, naming the run that trained it
        reused = logged[logged["tags.eskin.trained"] == "reused"]
        assert len(reused) >= 3 and reused["tags.eskin.reused_from"].str.len().min() == 32
        if task is None:
            continue
        trained = found[found["tags.eskin.scene"] == "single_force"].iloc[0]
        assert trained["tags.eskin.dataset_digest"] == digest
        assert trained["tags.eskin.git_commit"] == head

    csv = root / "compare.csv"
    eskin_cli(["compare", "--format", "csv", "--output", str(csv)], root, env)
    table = pd.read_csv(csv).set_index("variant")
    assert {"q-logistic", "q-ridge", "force-rf"} <= set(table.index)
    assert table.loc["q-logistic", "train.detect.model"] == "logistic"
    assert table.loc["q-ridge", "train.stretch.model"] == "ridge"
    assert table.loc["force-rf", "train.force.model.single_force"] == "random_forest"
    # runs not reused: the detector of each of the two scenes (two_force's counts its
    # contacts) and the two-force pairs' scores run
    assert table.loc["q-logistic", "runs"] == 3 and table.loc["q-logistic", "run time s"] > 0
    assert 0.5 < table.loc["q-logistic", "contact acc"] <= 1
    assert -1 < table.loc["force-rf", "force R²"] <= 1
    printed = eskin_cli(["compare", "--scheme", "stratified"], root, env).stdout
    assert "q-ridge" in printed and "stretch R²" in printed


def test_a_registered_model_reproduces_its_runs_out_of_fold_predictions(scratch):
    root, env = scratch
    done = eskin_cli(["reproduce", "single_force.localise.x"], root, env)
    assert "reproduced" in done.stdout and "NOT" not in done.stdout, done.stdout
    # progress on stderr: each scheme as it starts and ends, its folds as a bar in between
    for number, scheme in enumerate(("stratified", "conditions"), 1):
        assert re.search(rf"^single_force.localise.x v\d+: {scheme} cross-validation "
                         rf"\({number} of 2\), 3 folds", done.stderr, re.M), done.stderr
        # tqdm's bar, cleared at its end (its last state drawn depends on the clock)
        assert f"single_force.localise.x {scheme} CV:   0%" in done.stderr, done.stderr
        assert re.search(rf"{scheme} cross-validation done in \d+ s, (\d+)/\1 predictions "
                         "identical$", done.stderr, re.M), done.stderr
    import mlflow
    mlflow.set_tracking_uri(env["MLFLOW_TRACKING_URI"])
    version = mlflow.MlflowClient().get_model_version("single_force.localise.x", "1")
    assert version.tags["eskin.dataset_digest"] == md5_file(
        root / "data" / "processed" / "single_force.parquet")
    assert version.tags["eskin.features_md5"] == md5_file(
        root / "data" / "features" / "single_force.parquet")
    missing = eskin_cli(["reproduce", "single_force.nothing"], root, env, check=False)
    assert missing.returncode == 1 and "no registered model 'single_force.nothing'" in \
        missing.stderr


def test_another_plan_is_a_second_dataset_version_and_the_audit_shows_both(scratch):
    root, env = scratch
    first = md5_file(root / "data" / "processed" / "single_force.parquet")
    # Fewer samples per condition in one scene: its stages run again, the other scene's
    # are reused (a new sim.seed would draw both, and cost CI minutes), and MLflow hears
    # of it in the last stage, `track`.
    run(["dvc", "exp", "run", "-n", "samples4", "-S", "scenes.single_force.samples=4"],
        root, env)
    second = md5_file(root / "data" / "processed" / "single_force.parquet")
    assert second != first

    csv = root / "audit.csv"
    eskin_cli(["audit", "--format", "csv", "--output", str(csv)], root, env)
    versions = pd.read_csv(csv, dtype=str).fillna("").set_index("dataset md5")
    assert {first, second} <= set(versions.index)
    assert versions.loc[second, "workspace"] == "yes" and versions.loc[first, "workspace"] == ""
    assert int(versions.loc[second, "rows"]) < int(versions.loc[first, "rows"])
    assert versions.loc[second, "source"] == versions.loc[first, "source"]  # the same skin
    assert versions.loc[second, "variants"] == "samples4"
    assert int(versions.loc[second, "runs"]) == 4  # stretch, force, detect, localise
    import mlflow
    mlflow.set_tracking_uri(env["MLFLOW_TRACKING_URI"])
    # every task run on the first dataset: the repro's, and those of force-rf, q-logistic,
    # q-ridge and c2-alpha, trained or reused
    on_first = mlflow.search_runs(experiment_names=["eskin"], filter_string=(
        f"tags.`eskin.dataset_digest` = '{first}' and tags.`eskin.kind` = 'task'"))
    assert int(versions.loc[first, "runs"]) == len(on_first) >= 8
    assert versions.loc[first, "committed"].split()[0] != "not"  # in the repro commit's lock
    printed = eskin_cli(["audit"], root, env).stdout
    assert f"{first} trained:" in printed and f"{second} trained:" in printed

    old = mlflow.search_runs(experiment_names=["eskin"], filter_string=(
        f"tags.`eskin.dataset_digest` = '{first}' and tags.`eskin.task` = 'force'"))
    report = eskin_cli(["audit", "--run", old.iloc[-1]["run_id"]], root, env).stdout
    assert f"dataset md5     {first}" in report
    assert "dataset in workspace  differs" in report and "dataset in DVC cache  ok" in report
    new = mlflow.search_runs(experiment_names=["eskin"], filter_string=(
        f"tags.`eskin.dataset_digest` = '{second}' and tags.`eskin.task` = 'force'"))
    report = eskin_cli(["audit", "--run", new.iloc[0]["run_id"]], root, env).stdout
    assert "dataset in workspace  ok" in report and "model in workspace    ok" in report
    # The first dataset's model still reproduces: its features come back from DVC's cache.
    done = eskin_cli(["reproduce", "single_force.localise.x", "--version", "1"], root, env)
    assert "reproduced" in done.stdout and ".dvc/cache" in done.stdout, done.stdout


def test_postgres_gone_mid_run_fails_the_stage_in_one_line_naming_the_server(scratch, lab):
    """The lab's PostgreSQL stops while the publish stage starts (the only stage that
    talks to MLflow): it ends, exit 1, with one line naming the tracking URI, within the
    tries eskin allows MLflow's client (not its default minutes). Runs that a killed
    stage left open are marked FAILED by the next (tests/test_stale_runs.py). Once the
    database is back, the stage logs again and leaves no run RUNNING."""
    import mlflow

    root, env = scratch
    database, tracking = lab
    started = time.monotonic()
    stage = subprocess.Popen([sys.executable, "-m", "stages.publish"], cwd=root, env=env,
                             text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    time.sleep(0.5)  # importing: nothing logged yet
    database.stop()
    try:
        _, stderr = stage.communicate(timeout=300)
    finally:
        database.start()
    assert stage.returncode == 1, stderr
    errors = [line for line in stderr.splitlines() if line.startswith("eskin: error:")]
    assert len(errors) == 1 and f"MLflow tracking at {tracking.uri} failed" in errors[0], stderr
    assert "while logging the pipeline" in errors[0]
    assert "Traceback" not in stderr and time.monotonic() - started < 120
    run_checked([sys.executable, "-m", "stages.publish"], root, env)
    found = mlflow.search_runs(experiment_names=["eskin"])
    assert "RUNNING" not in set(found["status"])
