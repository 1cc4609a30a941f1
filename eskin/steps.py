"""Pipeline steps shared by the DVC stages and the ``eskin`` command line.

Each reads its params sections, calls the library, and writes its outputs:
the same code runs under ``dvc repro`` and by hand.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from eskin.acquisition.session import LOG_NAME, acquire_scene
from eskin.config import scene_plan, section, skin_params
from eskin.data.importer import copy_import, find_import, import_to_dataset
from eskin.data.ingest import ingest_log
from eskin.data.schema import write_dataset, write_quarantine
from eskin.device.faults import LinkFaults


def acquire(params: dict[str, Any], scene: str, raw_dir: Path, *, progress: bool = True) -> str:
    """Acquire (or import) ``scene`` into ``raw_dir``; returns a one-paragraph summary."""
    plan = scene_plan(params, scene)
    settings = section(params, "acquire")
    if settings["source"] == "import":
        source = section(params, f"scenes.{scene}").get("import_path")
        if not source:
            raise ValueError(f"acquire.source is 'import' but scenes.{scene}.import_path is unset")
        if Path(source).is_dir():
            raise ValueError(f"scenes.{scene}.import_path = {source!r} is a directory; name "
                             "the CSV or Parquet file in it")
        target = copy_import(Path(source), raw_dir, plan.kind)
        return f"{scene}: imported {source} as {target}"
    board = section(params, "sim_board")
    report = acquire_scene(
        plan, raw_dir, source=settings["source"], sim=skin_params(params),
        rest_length_mm=float(settings["rest_length_mm"]), port=settings.get("port"),
        corrupt_fraction=float(board["corrupt_fraction"]),
        faults=LinkFaults.from_mapping(board.get("faults")),
        frame_period_ms=int(board["frame_period_ms"]), timeout_s=float(settings["timeout_s"]),
        max_attempts=int(settings["max_attempts"]),
        reconnect_s=float(settings["reconnect_s"]),
        max_jump_counts=float(settings["max_jump_counts"]),
        indenters=settings.get("indenters", "person"), progress=progress)
    return report.summary()


def ingest(params: dict[str, Any], scene: str, raw_dir: Path, processed_dir: Path) -> str:
    """Raw data of ``scene`` → ``<processed_dir>/<scene>.parquet`` and its quarantine CSV."""
    plan = scene_plan(params, scene)
    bad_rows = section(params, "ingest.bad_rows")
    out = Path(processed_dir) / f"{scene}.parquet"
    if section(params, "acquire.source") == "import":
        # Streamed to Parquet chunk by chunk: memory does not grow with the file.
        quarantine, metadata = import_to_dataset(find_import(raw_dir), plan.kind, out,
                                                 bad_rows=bad_rows, scene=scene)
        rows = metadata["source"]["rows_in_file"] - metadata["source"]["rows_quarantined"]
    else:
        result = ingest_log(Path(raw_dir) / LOG_NAME, plan, bad_rows=bad_rows)
        write_dataset(result.frame, plan.kind, out, result.metadata)
        quarantine, rows = result.quarantine, len(result.frame)
    write_quarantine(quarantine, Path(processed_dir) / f"{scene}.quarantine.csv")
    note = f"; {len(quarantine)} row(s) quarantined" if quarantine else ""
    return f"{scene}: {rows} rows → {out}{note}"
