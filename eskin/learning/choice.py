"""Which model each task of each scene trains, and with which hyperparameters: read from
params.yaml's ``train:`` section without importing a model (scikit-learn is imported by
:mod:`eskin.learning.estimators`, which builds them).

``train.<task>`` is shared by every scene; its ``model`` is a name, or a name per kind of
scene. The settings stage writes, per scene and task, only the part of the section that
the scene's training reads (:func:`task_section`). A knob of one kind's model then reruns
only that kind's training stages. DVC's templating, which generates the training
stages, cannot look up a scene's kind itself.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from eskin.kinds import ONE_CONTACT

if TYPE_CHECKING:
    from eskin.config.train import TaskModels
    from eskin.skin import AnySkin

# Models that read a row/column skin's x and y terminals (ForceProfile, ActiveTerminals),
# each with the generic model a channel array trains instead: the same gradient boosting
# on the channels themselves (docs/learning.md).
ROW_COLUMN_MODELS: dict[str, str] = {"physics_profile": "hist_gradient_boosting",
                                     "active_terminals": "hist_gradient_boosting"}

CONFIGURATIONS = ("tuned", "paper")


def model_settings(task_params: TaskModels, configuration: str = "tuned",
                   kind: str = ONE_CONTACT.name) -> tuple[str, dict[str, Any]]:
    """(model name, its hyperparameters) from a ``train.<task>`` section
    (:class:`eskin.config.TaskModels`: ``params.train.force``), for a scene of ``kind``.

    ``configuration`` is ``train.configuration``: ``tuned`` uses the task's
    ``model`` (chosen by ``make bench``), ``paper`` its ``paper`` entry. ``model`` is a
    name, or a name per kind (``{single_force: logistic, two_force: paper}``); the
    hyperparameters are the entry of that name beside it (``model_extra``).
    """
    if configuration not in CONFIGURATIONS:
        raise ValueError(f"train.configuration must be one of {CONFIGURATIONS}, "
                         f"got {configuration!r}")
    chosen = getattr(task_params, "model", None)
    if chosen is None:
        raise KeyError("the task's params need a 'model' entry naming a registry model")
    if isinstance(chosen, Mapping):
        if kind not in chosen:
            raise KeyError(f"the task's model names no model for {kind} scenes "
                           f"(it has {', '.join(map(str, chosen))})")
        chosen = chosen[kind]
    name = "paper" if configuration == "paper" else str(chosen)
    return name, hyperparameters(task_params, name)


def hyperparameters(task_params: TaskModels, name: str) -> dict[str, Any]:
    """The hyperparameters of model ``name`` in a ``train.<task>`` section (none: {})."""
    hyper = (task_params.model_extra or {}).get(name) or {}
    if not isinstance(hyper, Mapping):
        raise ValueError(f"hyperparameters of {name!r} must be a mapping, got {hyper!r}")
    return dict(hyper)


def model_for_skin(task_params: TaskModels, name: str, hyper: dict[str, Any],
                   skin: AnySkin) -> tuple[str, dict[str, Any], str]:
    """(model, hyperparameters, note) that train on ``skin``: ``name`` as it is, or, for a
    model that reads row/column terminals on a channel array, its generic model
    (:data:`ROW_COLUMN_MODELS`) with its hyperparameters, and a note saying so."""
    generic = ROW_COLUMN_MODELS.get(name)
    if skin.row_column or generic is None:
        return name, hyper, ""
    return generic, hyperparameters(task_params, generic), (
        f"{name} reads a row/column skin's x and y terminals and this scene is an "
        f"{skin.describe()}: trained {generic} instead")


def task_section(task_params: TaskModels, configuration: str, kind: str) -> dict[str, Any]:
    """The part of a ``train.<task>`` section a scene of ``kind`` trains from, itself a
    ``train.<task>`` section: its model by name, that model's hyperparameters and, for a
    row/column model, those of the generic model a channel array trains instead.
    :func:`model_settings` and :func:`model_for_skin` give the same on it as on the whole
    section."""
    name, hyper = model_settings(task_params, configuration, kind)
    section: dict[str, Any] = {"model": name, name: hyper}
    generic = ROW_COLUMN_MODELS.get(name)
    if generic is not None:
        section[generic] = hyperparameters(task_params, generic)
    return section
