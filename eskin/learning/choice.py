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

# Models that read a row/column skin's x and y terminals (ForceProfile, ActiveTerminals,
# PeakWindow), each with the generic model a channel array trains instead: the same
# gradient boosting (for PeakWindow, logistic regression) on the channels themselves
# (docs/learning.md).
ROW_COLUMN_MODELS: dict[str, str] = {"physics_profile": "hist_gradient_boosting",
                                     "active_terminals": "hist_gradient_boosting",
                                     "peak_window": "logistic"}

# Models whose fit grows with the channels times the nodes of an axis, by kind of scene
# and role, each with the model a skin of longer axes trains instead and the most
# terminals an axis may have for the first (PeakWindow locates one contact only). A
# multinomial logistic regression on every channel (Newton's Hessian is that product
# squared) costs per row, past 14 terminals an axis, over 3× what it costs on the paper's
# 10 × 10; PeakWindow hardly grows (make bench's localise_cost, docs/learning.md).
LONG_AXIS_MODELS: dict[tuple[str, str, str], tuple[str, int]] = {
    (ONE_CONTACT.name, "localise", "logistic"): ("peak_window", 14)}

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
                   skin: AnySkin, role: str, kind: str) -> tuple[str, dict[str, Any], str]:
    """(model, hyperparameters, note) that train on ``skin`` in ``role`` for a scene of
    ``kind``: ``name`` as it is, or, with its hyperparameters and a note saying so, for a
    model that reads row/column terminals on a channel array, its generic model
    (:data:`ROW_COLUMN_MODELS`), and for one whose cost grows with the nodes on a skin of
    longer axes, the model that scales (:data:`LONG_AXIS_MODELS`)."""
    generic = ROW_COLUMN_MODELS.get(name)
    if not skin.row_column and generic is not None:
        return generic, hyperparameters(task_params, generic), (
            f"{name} reads a row/column skin's x and y terminals and this scene is an "
            f"{skin.describe()}: trained {generic} instead")
    scaling, most = LONG_AXIS_MODELS.get((kind, role, name), (None, 0))
    if skin.row_column and scaling is not None and max(skin.rows, skin.columns) > most:
        return scaling, hyperparameters(task_params, scaling), (
            f"{name}'s fit grows with the channels times the nodes, and this scene's "
            f"{skin.describe()} has more than {most} terminals on an axis: trained {scaling} "
            "instead")
    return name, hyper, ""


def chosen_model(task_params: TaskModels, configuration: str, kind: str, skin: AnySkin,
                 role: str) -> tuple[str, dict[str, Any], str]:
    """(model, hyperparameters, note) a scene of ``kind`` on ``skin`` trains for a task of
    ``role`` from its ``train.<task>`` section: :func:`model_settings`, then
    :func:`model_for_skin`."""
    return model_for_skin(task_params, *model_settings(task_params, configuration, kind), skin,
                          role, kind)


def task_section(task_params: TaskModels, configuration: str, kind: str) -> dict[str, Any]:
    """The part of a ``train.<task>`` section a scene of ``kind`` trains from, itself a
    ``train.<task>`` section: its model by name, that model's hyperparameters and those of
    a model a skin may train instead (:func:`model_for_skin`).
    :func:`model_settings` and :func:`model_for_skin` give the same on it as on the whole
    section."""
    name, hyper = model_settings(task_params, configuration, kind)
    section: dict[str, Any] = {"model": name, name: hyper}
    generic = ROW_COLUMN_MODELS.get(name)
    if generic is not None:
        section[generic] = hyperparameters(task_params, generic)
    # a model a skin of longer axes trains instead, where params set its hyperparameters
    # (the section does not know the skin; without them it trains on its defaults)
    for (of_kind, _, chosen), (scaling, _) in LONG_AXIS_MODELS.items():
        if (of_kind, chosen) == (kind, name) and scaling in (task_params.model_extra or {}):
            section[scaling] = hyperparameters(task_params, scaling)
    return section
