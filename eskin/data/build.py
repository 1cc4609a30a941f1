"""The ingest step: a scene's raw data (its raw log, or the file it imported) into the
processed dataset, shared by the DVC stage and the ``eskin`` command line."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from eskin.acquisition.plan import scene_plan
from eskin.acquisition.rawlog import LOG_NAME
from eskin.config import section
from eskin.data.importer import find_import, import_to_dataset
from eskin.data.ingest import ingest_log, live_frames
from eskin.data.schema import write_dataset, write_quarantine


def ingest(params: dict[str, Any], scene: str, raw_dir: Path, processed_dir: Path) -> str:
    """Raw data of ``scene`` → ``<processed_dir>/<scene>.parquet``, its quarantine CSV and
    the frames recorded live (``<scene>.live.parquet``)."""
    plan = scene_plan(params, scene)
    bad_rows = section(params, "ingest.bad_rows")
    out = Path(processed_dir) / f"{scene}.parquet"
    if section(params, f"scenes.{scene}.source") == "import":
        # Streamed to Parquet chunk by chunk: memory does not grow with the file.
        quarantine, metadata = import_to_dataset(find_import(raw_dir), plan.kind, out,
                                                 bad_rows=bad_rows, scene=scene,
                                                 imported_from=section(
                                                     params, f"scenes.{scene}.import_path"))
        rows = metadata["source"]["rows_in_file"] - metadata["source"]["rows_quarantined"]
        live = live_frames(None)  # an imported scene has no board to record from
    else:
        result = ingest_log(Path(raw_dir) / LOG_NAME, plan, bad_rows=bad_rows)
        write_dataset(result.frame, plan.kind, out, result.metadata)
        quarantine, rows, live = result.quarantine, len(result.frame), result.live
    write_quarantine(quarantine, Path(processed_dir) / f"{scene}.quarantine.csv")
    live.to_parquet(live_path(processed_dir, scene), index=False)
    note = f"; {len(quarantine)} row(s) quarantined" if quarantine else ""
    if len(live):
        note += (f"; {len(live)} live-recorded frame(s) of {live['session'].nunique()} "
                 f"session(s) → {live_path(processed_dir, scene)}")
    return f"{scene}: {rows} rows → {out}{note}"


def live_path(processed_dir: Path, scene: str) -> Path:
    """The frames ``eskin live --record`` kept (no labels: not training data)."""
    return Path(processed_dir) / f"{scene}.live.parquet"
