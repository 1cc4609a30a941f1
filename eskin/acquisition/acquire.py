"""The acquisition step, shared by the DVC stage and the ``eskin`` command line, and
the checks every scene passes before any acquisition starts.

It reads its params sections, calls the library, and writes its outputs: the same
code runs under ``dvc repro`` and by hand. (Ingest is :mod:`eskin.data.build`, so that
the ingest stage does not depend on the acquisition's code.)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from eskin.acquisition.plan import scene_plan
from eskin.acquisition.session import acquire_scene
from eskin.config import section, validating
from eskin.data.importer import check_layout, copy_import
from eskin.data.schema import DatasetError
from eskin.device.faults import LinkFaults
from eskin.device.physics import skin_params


def acquire(params: dict[str, Any], scene: str, raw_dir: Path, *, progress: bool = True) -> str:
    """Acquire (or import) ``scene`` into ``raw_dir``; returns a one-paragraph summary."""
    with validating():  # every scene is checked, but only this one's settings are used
        check_scenes(params)
    plan = scene_plan(params, scene)
    settings = section(params, "acquire")
    scene_settings = section(params, f"scenes.{scene}")
    if scene_settings["source"] == "import":
        source = Path(scene_settings["import_path"])  # checked by check_scenes above
        target = copy_import(source, raw_dir, plan.kind)
        return f"{scene}: imported {source} as {target}"
    board = section(params, "sim_board")
    report = acquire_scene(
        plan, raw_dir, source=scene_settings["source"], sim=skin_params(params),
        rest_length_mm=float(settings["rest_length_mm"]), port=scene_settings.get("port"),
        corrupt_fraction=float(board["corrupt_fraction"]),
        faults=LinkFaults.from_mapping(board.get("faults")),
        frame_period_ms=int(board["frame_period_ms"]), timeout_s=float(settings["timeout_s"]),
        max_attempts=int(settings["max_attempts"]),
        reconnect_s=float(settings["reconnect_s"]),
        max_jump_counts=float(settings["max_jump_counts"]),
        indenters=settings.get("indenters", "person"), progress=progress)
    return report.summary()


def check_scenes(params: dict[str, Any]) -> None:
    """What can be wrong with any scene, found before the first acquisition starts (so a
    typo in the last scene does not wait for the first to be recorded): an import file
    missing, unreadable or not in its kind's layout; a plan with fewer trials than the
    grouped folds. One line naming the scene, the key and the file."""
    cv = section(params, "cv")
    for name, scene in section(params, "scenes").items():
        if scene["source"] == "import":
            path = check_import_path(params, name)
            try:
                check_layout(Path(path), scene["kind"])
            except DatasetError as err:
                raise DatasetError(f"scenes.{name}.import_path: {err}") from None
            continue
        trials = len(scene_plan(params, name).conditions)
        if "grouped" in cv["schemes"] and trials < int(cv["folds"]):
            raise ValueError(f"scenes.{name}: {trials} trials (conditions), but grouped CV "
                             f"with cv.folds = {cv['folds']} needs at least {cv['folds']}; "
                             "add stretches, forces or nodes, or lower cv.folds")


def check_import_path(params: dict[str, Any], scene: str) -> str:
    """``scenes.<scene>.import_path``, checked to be a readable file (not a directory)."""
    source = section(params, f"scenes.{scene}").get("import_path")
    if not source:
        raise ValueError(f"scenes.{scene}: source is 'import' but import_path is unset")
    path = Path(source)
    if path.is_dir():
        raise ValueError(f"scenes.{scene}.import_path = {source!r} is a directory; name "
                         "the CSV or Parquet file in it")
    if not path.exists():
        raise FileNotFoundError(f"scenes.{scene}.import_path = {source!r}: no such file")
    try:
        with path.open("rb") as handle:
            handle.read(1)
    except OSError as err:
        raise ValueError(f"scenes.{scene}.import_path = {source!r}: cannot be read "
                         f"({err.strerror})") from None
    return source
