"""`eskin promote`'s refusal of a stack trained on more than one features version (the
promotion itself runs against a real MLflow server in tests/test_pipeline_tracking.py)."""

import pytest
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
