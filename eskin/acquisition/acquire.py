"""The acquisition step, shared by the DVC stage and the ``eskin`` command line, and
the checks every scene passes before any acquisition starts.

It reads its params sections, calls the library, and writes its outputs: the same
code runs under ``dvc repro`` and by hand. (Ingest is :mod:`eskin.steps.ingest`, so that
the prepare stage does not depend on the acquisition's code.)
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from eskin.acquisition.runner import AcquisitionReport
from eskin.acquisition.session import acquire_scene
from eskin.config.acquisition import Acquire, Sim, SimBoard
from eskin.config.cv import CV
from eskin.config.scenes import Scene, scene_skin
from eskin.data.importer import check_import, copy_import
from eskin.data.plan import plan_from_params
from eskin.device.faults import LinkFaults
from eskin.device.physics import skin_params


@dataclass(frozen=True)
class Acquired:
    """What :func:`acquire` did: the scene's raw data (``imported``: the folder of the
    copies of its import files; ``report``: the acquisition's, for a board or the
    simulator)."""

    scene: str
    raw_dir: Path
    imported: Path | None
    report: AcquisitionReport | None
    summary: str


def acquire(name: str, scene: Scene, raw_dir: Path, *, acquire: Acquire, sim: Sim,
            board: SimBoard, progress: bool = True) -> Acquired:
    """Acquire (or import) scene ``name`` (its params section ``scene``) into ``raw_dir``,
    with the ``acquire``, ``sim`` and ``sim_board`` sections. Run :func:`check_scenes`
    on every scene first (the stage and the command line do)."""
    if scene.source == "import":
        copies = copy_import(name, scene, raw_dir)
        return Acquired(name, Path(raw_dir), copies[0].parent, None,
                        f"{name}: imported {len(copies)} file(s) of {scene.import_.path} "
                        f"into {copies[0].parent}")
    plan = plan_from_params(name, scene)
    report = acquire_scene(
        plan, raw_dir, source=scene.source, sim=skin_params(sim),
        rest_length_mm=float(acquire.rest_length_mm), port=scene.port,
        corrupt_fraction=float(board.corrupt_fraction),
        faults=LinkFaults.from_mapping(board.faults.model_dump(exclude_unset=True)),
        frame_period_ms=int(board.frame_period_ms), timeout_s=float(acquire.timeout_s),
        max_attempts=int(acquire.max_attempts),
        max_interruptions=int(acquire.max_interruptions),
        reconnect_s=float(acquire.reconnect_s),
        max_jump_counts=float(acquire.max_jump_counts),
        indenters=acquire.indenters, progress=progress)
    return Acquired(name, Path(raw_dir), None, report, report.summary())


def check_scenes(scenes: Mapping[str, Scene], cv: CV) -> None:
    """What can be wrong with any scene, found before the first acquisition starts (so a
    typo in the last scene does not wait for the first to be recorded): an import file
    missing, unreadable or not in its kind's layout; a plan with fewer trials than the
    conditions folds; a board's scene on a skin no board reads (a channel array). One line
    naming the scene, the key and the file. (The stage calls it under
    :func:`eskin.config.validating`: checking other scenes is not reading knobs.)"""
    for name, scene in scenes.items():
        skin = scene_skin(scene)
        if scene.source != "import" and not skin.row_column:
            raise ValueError(f"scenes.{name}: source {scene.source!r} reads a row/column skin "
                             f"over protocol v1, but its skin is an {skin.describe()}: record "
                             "it with its own instrument and import it (source: import, "
                             "import: {path: ...})")
        if scene.source == "import":
            check_import(name, scene)
            continue
        plan = plan_from_params(name, scene)
        conditions = len(plan.conditions) // plan.repeats
        if "conditions" in cv.schemes and conditions < int(cv.folds):
            raise ValueError(f"scenes.{name}: {conditions} condition(s), but conditions CV "
                             f"with cv.folds = {cv.folds} needs at least {cv.folds}; "
                             "add stretches, forces or nodes, or lower cv.folds")
