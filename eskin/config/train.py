"""params.yaml's ``train``: the model and hyperparameters of each task."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, create_model

from eskin.catalog import TASK_NAMES
from eskin.config.base import Section
from eskin.kinds import KIND_NAMES


class TaskModels(BaseModel):
    """``model: <name>`` (or a name per kind of scene) and, beside it, candidates'
    hyperparameters by name (a model with no entry takes its defaults:
    ``-S train.<task>.model=<name>``). The name itself is checked against the registry
    by the train step, which imports it."""

    model_config = ConfigDict(extra="allow", strict=True)
    model: str | dict[Literal[KIND_NAMES], str]  # type: ignore[valid-type]
    __pydantic_extra__: dict[str, dict[str, Any]]


# train: ``configuration``, then one TaskModels per task, shared by every scene (the
# stage of scene s and task t reads train.configuration and train.<t>).
Train = create_model(
    "Train", __base__=Section, configuration=(Literal["tuned", "paper"], ...),
    **{name: (TaskModels, ...) for name in TASK_NAMES})
