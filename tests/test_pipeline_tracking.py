"""The pipeline under real DVC and MLflow: `dvc repro`, `dvc exp run -S`, `dvc metrics show`.

A scratch copy of the project (small scenes) runs the real stages; MLflow logs
to an SQLite store in the scratch directory through MLFLOW_TRACKING_URI.
"""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from conftest import ROOT, small_scenes, write_params

from eskin.data.schema import md5_file

COPIED = ["eskin", "stages", "dvc.yaml", ".dvcignore", ".gitignore", "pyproject.toml",
          "README.md"]


def run(args, cwd, env):
    done = subprocess.run(args, cwd=cwd, env=env, text=True, capture_output=True, timeout=900)
    assert done.returncode == 0, f"{' '.join(args)} failed:\n{done.stdout}\n{done.stderr}"
    return done.stdout


@pytest.fixture(scope="module")
def scratch(tmp_path_factory, repo_params):
    root = tmp_path_factory.mktemp("pipeline")
    for name in COPIED:
        source = ROOT / name
        if source.is_dir():
            shutil.copytree(source, root / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(source, root / name)
    params = small_scenes(repo_params)
    params["cv"].update(n_jobs=1, folds=5)
    params["report"].update(dpi=60, page_dpi=50)
    for scene, task in (("single_force", "force"), ("two_force", "force1"),
                        ("two_force", "force2")):
        params["train"][scene][task]["paper"]["subsample"] = 200
    for scene in ("single_force", "two_force"):
        params["train"][scene]["localise"]["paper"]["n_estimators"] = 20
    write_params(root, params)
    bin_dir = str(Path(sys.executable).parent)  # dvc, and the python DVC's stages call
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}",
           "DVC_NO_ANALYTICS": "1", "MLFLOW_ENABLE_TELEMETRY": "false",
           "MLFLOW_TRACKING_URI": f"sqlite:///{root / 'mlflow.db'}",
           "GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@t", "GIT_COMMITTER_NAME": "t",
           "GIT_COMMITTER_EMAIL": "t@t"}
    env.pop("DVC_ROOT", None)
    run(["git", "init", "-q"], root, env)
    run(["dvc", "init", "-q"], root, env)
    run(["dvc", "config", "core.analytics", "false"], root, env)
    run(["git", "add", "-A"], root, env)
    run(["git", "commit", "-qm", "scratch"], root, env)
    run(["dvc", "repro"], root, env)
    run(["git", "add", "-A"], root, env)
    run(["git", "commit", "-qm", "repro"], root, env)
    return root, env


def test_dvc_metrics_show_lists_the_headline_metrics(scratch):
    root, env = scratch
    shown = json.loads(run(["dvc", "metrics", "show", "--json"], root, env))
    metrics = {}
    for data in shown.values():
        for path, content in data["data"].items():
            metrics[path] = content["data"]
    single = "reports/metrics/single_force/{}.json"
    assert 0 < metrics[single.format("stretch")]["stratified"]["stretch"]["r2"] <= 1
    assert "r2" in metrics[single.format("force")]["grouped"]["force"]
    assert "accuracy" in metrics[single.format("detect")]["stratified"]["contact"]
    for axis in ("x", "y"):
        assert "accuracy" in metrics[single.format("localise")]["stratified"][axis]
    table = run(["dvc", "metrics", "show"], root, env)
    assert "stratified.stretch.r2" in table and "stratified.contact.accuracy" in table


def test_a_second_force_model_is_a_second_mlflow_run_on_the_same_dataset(scratch, repo_params):
    root, env = scratch
    out = run(["dvc", "exp", "run", "-n", "force-rf", "-S",
               "train.single_force.force.model=random_forest"], root, env)
    assert "train@single_force-force" in out
    assert "Running stage 'train@single_force-stretch'" not in out  # only what changed reruns

    import mlflow
    mlflow.set_tracking_uri(env["MLFLOW_TRACKING_URI"])
    runs = mlflow.search_runs(experiment_names=["eskin"],
                              filter_string="tags.`eskin.task` = 'force' and "
                                            "tags.`eskin.scene` = 'single_force'")
    default = repo_params["train"]["single_force"]["force"]["model"]
    assert sorted(runs["params.model"]) == sorted([default, "random_forest"])
    digest = md5_file(root / "data" / "processed" / "single_force.parquet")
    assert set(runs["tags.eskin.dataset_digest"]) == {digest}
    experiment_run = runs[runs["params.model"] == "random_forest"].iloc[0]
    assert experiment_run["tags.eskin.dvc_experiment"] == "force-rf"
    assert experiment_run["params.random_forest.n_estimators"] == "100"

    client = mlflow.MlflowClient()
    for run_id in runs["run_id"]:
        run_ = client.get_run(run_id)
        inputs = run_.inputs.dataset_inputs
        assert [i.dataset.digest for i in inputs] == [digest]
        assert run_.data.tags["mlflow.parentRunId"]
        assert run_.data.tags["eskin.git_commit"]
        assert "stratified.force.r2" in run_.data.metrics
    # The dataset version DVC records is the digest MLflow carries.
    lock = yaml.safe_load((root / "dvc.lock").read_text())
    outs = lock["stages"]["ingest@single_force"]["outs"]
    assert digest in {o["md5"] for o in outs}


def test_the_report_stage_writes_the_readme_table_and_dvc_plots_render(scratch):
    root, env = scratch
    readme = (root / "README.md").read_text()
    assert "| stretch R² [paper] | 0." in readme
    assert (root / "reports" / "index.html").stat().st_size > 10_000
    run(["dvc", "plots", "show", "-o", str(root / "dvc_plots")], root, env)
    assert (root / "dvc_plots" / "index.html").exists()


def test_a_repro_groups_its_task_runs_under_one_pipeline_run(scratch):
    root, env = scratch
    import mlflow
    mlflow.set_tracking_uri(env["MLFLOW_TRACKING_URI"])
    runs = mlflow.search_runs(experiment_names=["eskin"],
                              filter_string="tags.`eskin.kind` = 'task' and "
                                            "tags.`eskin.dvc_experiment` = ''")
    assert len(runs) == 7
    assert runs["tags.mlflow.parentRunId"].nunique() == 1
    model_dir = Path(runs.iloc[0]["artifact_uri"].removeprefix("file://"))
    assert model_dir.is_relative_to(root)
