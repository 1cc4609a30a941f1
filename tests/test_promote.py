"""`eskin promote`'s refusal of a stack trained on more than one features version, and its
warning when the alias goes to models that score worse (on a real MLflow store of a few
runs; the promotion of a whole pipeline's stack runs against a real MLflow server in
tests/test_pipeline_tracking.py)."""

import pytest
from conftest import ROOT
from mlflow.entities.model_registry import ModelVersion, ModelVersionTag

from eskin.deploy.stack import StackError
from eskin.tracking.registry import one_features_version


def version(name: str, features_md5: str) -> ModelVersion:
    return ModelVersion(name, "1", 0, tags=[ModelVersionTag("eskin.features_md5", features_md5)])


def test_a_stack_of_one_features_version_gives_its_md5():
    stack = [version("single_force.force", "a" * 32), version("single_force.stretch", "a" * 32)]
    assert one_features_version(stack, "single_force", "the models", "fix it") == "a" * 32


def test_a_stack_of_two_features_versions_is_refused_in_one_line_naming_both():
    stack = [version("single_force.force", "a" * 32), version("single_force.stretch", "b" * 32)]
    with pytest.raises(StackError) as refused:
        one_features_version(stack, "single_force", "the models of pipeline run 1",
                             "promote another")
    message = str(refused.value)
    assert "\n" not in message and "a" * 32 in message and "b" * 32 in message
    assert message.startswith("the models of pipeline run 1 of single_force were trained on "
                              "different features versions")
    assert message.endswith(": promote another")


def logged_pipeline(client, experiment: str, name: str, scores: dict[str, float]) -> None:
    """A pipeline run ``name`` whose task runs of single_force each trained and registered
    a model, scoring ``scores`` (task → conditions-CV headline score)."""
    pipeline = client.create_run(experiment, run_name=name, tags={"eskin.kind": "pipeline"})
    for task, score in scores.items():
        md5 = f"{name}-{task}"
        run = client.create_run(experiment, tags={
            "eskin.kind": "task", "mlflow.parentRunId": pipeline.info.run_id,
            "eskin.scene": "single_force", "eskin.task": task, "eskin.trained": "here",
            "eskin.model_md5": md5})
        client.log_metric(run.info.run_id, f"conditions.{task}.r2", score)
        client.set_terminated(run.info.run_id)
        client.create_model_version(f"single_force.{task}", f"runs:/{run.info.run_id}/{task}",
                                    run_id=run.info.run_id, tags={
                                        "eskin.target": task, "eskin.model_md5": md5,
                                        "eskin.features_md5": "f" * 32})
    client.set_terminated(pipeline.info.run_id)


@pytest.mark.heavy
def test_promoting_a_worse_stack_says_so_in_one_line_and_proceeds(tmp_path, monkeypatch,
                                                                    capsys):
    """The issue's case: champion went to a force model of 0.859 over one of 0.940 without
    a word. Now one line on stderr gives both scores (and only for the models that are
    worse), and the alias moves all the same: a rollback, or scores of another dataset
    version, are reasons to promote a lower score."""
    from mlflow import MlflowClient

    from eskin import cli
    from eskin.tracking import registry

    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow.db'}")
    monkeypatch.chdir(ROOT)  # params.yaml's scenes
    client = MlflowClient()
    experiment = client.create_experiment("eskin", artifact_location=(tmp_path / "a").as_uri())
    for name in ("model.force", "model.stretch"):
        client.create_registered_model(name.replace("model", "single_force"))
    logged_pipeline(client, experiment, "good", {"force": 0.940, "stretch": 0.990})
    logged_pipeline(client, experiment, "worse", {"force": 0.8585, "stretch": 0.995})

    first = registry.promote("single_force", variant="good")
    assert first.worse == () and registry.render_downgrades(first) is None  # nothing held it
    capsys.readouterr()  # this test's own store, made by an MLflow imported before eskin's
    assert cli.main(["promote", "single_force", "--experiment", "worse"]) == 0
    out, err = capsys.readouterr()
    assert "(worse)" in out.splitlines()[0] and "warning" not in out
    assert err == ("eskin: warning: single_force's 'champion' went to models that score worse "
                   "than the ones that held it (conditions CV): single_force.force v2 force r2 "
                   "0.859 against v1's 0.940\n"), err
    holders = {m.name: str(m.aliases["champion"]) for m in client.search_registered_models()}
    assert holders == {"single_force.force": "2", "single_force.stretch": "2"}  # it proceeded
    back = registry.promote("single_force", variant="good")  # force better, stretch worse
    assert [(d.name, d.version, d.replaced, d.new, d.old) for d in back.worse] == [
        ("single_force.stretch", "1", "2", 0.990, 0.995)]
