"""The project's experiment keeps its artifacts in this project's ``mlruns/``.

MLflow fixes an artifact location once, as an absolute path: a local store resolves a
relative one against the working directory when the experiment is made
(``mlflow.utils.uri.resolve_uri_if_local``), each run copies its experiment's into its own
``artifact_uri``, and no API moves either. So a project copied with its ``mlflow.db``
(``cp -a``, a moved directory) found the experiment ``eskin`` and wrote its runs'
artifacts into the original's ``mlruns/``. MLflow's relocatable form, ``mlflow-artifacts:``,
needs a tracking server (the lab's, eskin/tracking/lab.py), which a clone's own SQLite
store has not. What is left is the experiment: the copied one is renamed, with its runs
(their artifacts stay where MLflow wrote them), and the project makes a new ``eskin``
whose root is its own ``mlruns/``.
"""

from __future__ import annotations

import sys
from pathlib import Path

from mlflow.entities import Experiment
from mlflow.exceptions import MlflowException
from mlflow.tracking import MlflowClient
from mlflow.utils.file_utils import local_file_uri_to_path
from mlflow.utils.uri import is_local_uri


def own_uri(project: Path) -> str:
    """A project's own store: SQLite in the project."""
    return f"sqlite:///{project / 'mlflow.db'}"


def artifact_root(project: Path) -> str:
    """A new experiment's artifact location in a project's own store."""
    return (project / "mlruns").as_uri()


def artifacts_elsewhere(experiment: Experiment, project: Path) -> bool:
    """Whether an experiment of the project's own store writes its artifacts on this
    machine but outside ``project/mlruns`` (the store was copied from another project)."""
    location = experiment.artifact_location
    if not location or not is_local_uri(location):
        return False
    return not _path(location).resolve().is_relative_to((project / "mlruns").resolve())


def _path(local_uri: str) -> Path:
    return Path(local_file_uri_to_path(local_uri))


def own_experiment(client: MlflowClient, name: str, project: Path) -> Experiment | None:
    """The experiment ``name`` of the project's own store, None if there is none yet: one
    copied from another project is set aside first (renamed, with its runs)."""
    experiment = client.get_experiment_by_name(name)
    if experiment is None or not artifacts_elsewhere(experiment, project):
        return experiment
    _set_aside(client, experiment)
    experiment = client.get_experiment_by_name(name)  # a parallel stage's new one, or none
    if experiment is not None and artifacts_elsewhere(experiment, project):
        raise MlflowException(f"experiment {name!r} keeps its artifacts in "
                              f"{_path(experiment.artifact_location)}, outside this project, "
                              "and could not be renamed")
    return experiment


def _set_aside(client: MlflowClient, experiment: Experiment) -> None:
    """Rename a copied experiment (keeping its runs under a name that says where their
    artifacts are), freeing its name for this project's own."""
    where = _path(experiment.artifact_location)
    aside = f"{experiment.name} (artifacts in {where})"
    try:
        client.rename_experiment(experiment.experiment_id, aside)
    except MlflowException:
        return  # a parallel stage renamed it first (the caller checks)
    client.set_experiment_tag(
        experiment.experiment_id, "mlflow.note.content",
        f"Copied with this project's mlflow.db: its runs' artifacts are in {where}, "
        "not in this project.")
    print(f"eskin: MLflow experiment {experiment.name!r} kept its artifacts in {where} "
          f"(mlflow.db copied from another project): renamed "
          f"{aside!r}; this project's runs go to a new {experiment.name!r} in its own mlruns/",
          file=sys.stderr)
