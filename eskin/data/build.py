"""The ingest step: a scene's raw data (its raw log, or the file it imported) into the
processed dataset, shared by the DVC stage and the ``eskin`` command line."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from eskin.acquisition.plan import plan_from_params
from eskin.acquisition.rawlog import LOG_NAME
from eskin.config import Ingest, Scene
from eskin.data.importer import find_import, import_to_dataset
from eskin.data.ingest import ingest_log, live_frames
from eskin.data.schema import write_dataset, write_quarantine


@dataclass(frozen=True)
class Ingested:
    """What :func:`ingest` wrote: the dataset (``rows`` rows), the quarantine CSV
    (``quarantined`` rows) and the live-recorded frames (``live_frames`` of them)."""

    scene: str
    path: Path
    rows: int
    quarantine_path: Path
    quarantined: int
    live_path: Path
    live_frames: int
    summary: str


def ingest(name: str, scene: Scene, raw_dir: Path, processed_dir: Path, *,
           ingest: Ingest) -> Ingested:
    """Raw data of scene ``name`` (its params section ``scene``) →
    ``<processed_dir>/<name>.parquet``, its quarantine CSV and the frames recorded live
    (``<name>.live.parquet``), with the ``ingest`` section."""
    plan = plan_from_params(name, scene)
    bad_rows = ingest.bad_rows
    out = Path(processed_dir) / f"{name}.parquet"
    if scene.source == "import":
        # Streamed to Parquet chunk by chunk: memory does not grow with the file.
        quarantine, metadata = import_to_dataset(find_import(raw_dir), plan.kind, out,
                                                 bad_rows=bad_rows, scene=name,
                                                 imported_from=scene.import_path)
        rows = metadata["source"]["rows_in_file"] - metadata["source"]["rows_quarantined"]
        live = live_frames(None, plan.skin)  # an imported scene has no board to record from
    else:
        result = ingest_log(Path(raw_dir) / LOG_NAME, plan, bad_rows=bad_rows)
        write_dataset(result.frame, plan.kind, out, result.metadata, skin=plan.skin)
        quarantine, rows, live = result.quarantine, len(result.frame), result.live
    quarantine_path = Path(processed_dir) / f"{name}.quarantine.csv"
    write_quarantine(quarantine, quarantine_path)
    live.to_parquet(live_path(processed_dir, name), index=False)
    note = f"; {len(quarantine)} row(s) quarantined" if quarantine else ""
    if len(live):
        note += (f"; {len(live)} live-recorded frame(s) of {live['session'].nunique()} "
                 f"session(s) → {live_path(processed_dir, name)}")
    return Ingested(name, out, int(rows), quarantine_path, len(quarantine),
                    live_path(processed_dir, name), len(live),
                    f"{name}: {rows} rows → {out}{note}")


def live_path(processed_dir: Path, scene: str) -> Path:
    """The frames ``eskin live --record`` kept (no labels: not training data)."""
    return Path(processed_dir) / f"{scene}.live.parquet"
