"""data/raw/<scene>/ → data/processed/<scene>.parquet (+ quarantine CSV and the frames
recorded live): the ingest step, shared by the DVC stage and the ``eskin`` command line.
(It is not in :mod:`eskin.acquisition`, so that the prepare stage does not depend on the
acquisition's code.)"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from eskin.catalog import PROCESSED_DIR, RAW_DIR
from eskin.config.base import DEFAULT_PARAMS, load_params, sections
from eskin.config.ingest import Ingest
from eskin.config.scenes import ImportedScene, Scene, Scenes, get_scene, scene_skin
from eskin.data.importer import find_import, import_recording, import_to_dataset
from eskin.data.ingest import Ingested, ingest_contents, live_frames
from eskin.data.plan import ScenePlan, plan_from_params
from eskin.data.rawlog import LOG_NAME, read_log_if_any
from eskin.data.schema import DatasetError, sha256_file, write_dataset, write_quarantine
from eskin.kinds import get_kind


def run(scene: str, params_path: Path | str = DEFAULT_PARAMS) -> str:
    params = load_params(sections(scenes=Scenes, ingest=Ingest), params_path)
    return ingest_at(scene, get_scene(params, scene, params_path), RAW_DIR / scene,
                     PROCESSED_DIR, ingest=params.ingest).summary


def ingest_log(path: Path, plan: ScenePlan, *, bad_rows: str = "error") -> Ingested:
    """The dataset of ``plan`` from the raw log at ``path`` (not yet written)."""
    path = Path(path)
    contents = read_log_if_any(path)
    if contents is None:
        raise DatasetError(f"{path}: no raw log; run `eskin acquire {plan.name}` first")
    return ingest_contents(contents, plan, where=str(path), sha256=sha256_file(path),
                           bad_rows=bad_rows)


@dataclass(frozen=True)
class IngestedFiles:
    """What :func:`ingest_at` wrote: the dataset (``rows`` rows), the quarantine CSV
    (``quarantined`` rows) and the live-recorded frames (``live_frames`` of them)."""

    scene: str
    path: Path
    rows: int
    quarantine_path: Path
    quarantined: int
    live_path: Path
    live_frames: int
    summary: str


def ingest_at(name: str, scene: Scene, raw_dir: Path, processed_dir: Path, *,
              ingest: Ingest) -> IngestedFiles:
    """Raw data of scene ``name`` (its params section ``scene``) →
    ``<processed_dir>/<name>.parquet``, its quarantine CSV and the frames recorded live
    (``<name>.live.parquet``), with the ``ingest`` section (its ``bad_rows`` unless the
    scene sets its own).

    A raw log is read whole and ingested by
    :func:`eskin.data.ingest.ingest_contents`, which reads and writes nothing. An
    imported file is streamed into the dataset as it is read
    (:func:`eskin.data.importer.import_to_dataset`), so that memory does not grow with a
    lab's recording: there the reading and the writing stay together."""
    every_scene = ingest.bad_rows
    bad_rows = scene.bad_rows or every_scene
    out = Path(processed_dir) / f"{name}.parquet"
    if scene.source == "import":
        quarantine, metadata = _import(name, scene, raw_dir, out, bad_rows)
        source = metadata["source"]
        rows = (source["rows_in_file"] - source["rows_quarantined"]
                - source.get("rows_at_rest", 0))
        live = live_frames(None, scene_skin(scene))  # an import has no board to record from
        hiccups, labels = _hiccup_note(metadata), _labels_note(metadata)
    else:
        plan = plan_from_params(name, scene)
        result = ingest_log(Path(raw_dir) / LOG_NAME, plan, bad_rows=bad_rows)
        write_dataset(result.frame, plan.kind, out, result.metadata, skin=plan.skin)
        quarantine, rows, live = result.quarantine, len(result.frame), result.live
        hiccups = labels = ""
    quarantine_path = Path(processed_dir) / f"{name}.quarantine.csv"
    write_quarantine(quarantine, quarantine_path)
    live.to_parquet(live_path(processed_dir, name), index=False)
    note = (f"; {len(quarantine)} row(s) quarantined{hiccups}" if quarantine else "") + labels
    if len(live):
        note += (f"; {len(live)} live-recorded frame(s) of {live['session'].nunique()} "
                 f"session(s) → {live_path(processed_dir, name)}")
    return IngestedFiles(name, out, int(rows), quarantine_path, len(quarantine),
                         live_path(processed_dir, name), len(live),
                         f"{name}: {rows} rows → {out}{note}")


def _import(name: str, scene: ImportedScene, raw_dir: Path, out: Path, bad_rows: str
            ) -> tuple[list[dict], dict]:
    """An import scene's copies under ``raw_dir`` → the dataset ``out``, streamed (the
    paper's layout) or a file at a time (a column map): memory does not grow with the
    recording."""
    spec, skin = scene.import_, scene_skin(scene)
    files = find_import(raw_dir, name)
    if spec.columns is None:
        return import_to_dataset(files[0], scene.kind, out, skin=skin, bad_rows=bad_rows,
                                 scene=name, imported_from=spec.path)
    return import_recording(files, spec, scene.kind, skin, out, bad_rows=bad_rows, scene=name)


def _hiccup_note(metadata: dict) -> str:
    """`` (12 dropped frames, 30 stale repeats)``: the sensor's hiccups among the
    quarantined rows, if any."""
    source = metadata["source"]
    parts = [f"{source[key]} {what}" for key, what in (("dropped_frames", "dropped frame(s)"),
                                                      ("stale_repeats", "stale repeat(s)"))
             if source.get(key)]
    return f" ({', '.join(parts)})" if parts else ""


def _labels_note(metadata: dict) -> str:
    """What an import's labels are made of, where the files alone do not say: the contact
    rule's share of contacts, rows at rest left out, a total force in place of
    per-contact forces."""
    source, note = metadata["source"], ""
    contact_n = (source.get("force") or {}).get("contact_n")
    if contact_n is not None and not get_kind(metadata["kind"]).several:
        note += (f"; {source['contact_share']:.0%} contacts (force > {contact_n:g} N over "
                 f"{_rest_words(source['force'].get('rest') or {})})")
    if source.get("rows_at_rest"):
        note += f"; {source['rows_at_rest']} row(s) at rest left out (every row presses)"
    if "force" in metadata.get("labels", []):
        note += ("; total force only: trains the total force and the contacts' positions, "
                 "cannot give per-contact forces")
    return note


def _rest_words(rest: dict) -> str:
    """What the contact rule measured the force from, by ``import.rest``'s rule."""
    rule = rest.get("rule", "low_tail")
    if rule == "first":
        head = f"{rest['rows']} row(s)" if "rows" in rest else f"{rest['seconds']:g} s"
        return f"each file's first {head}"
    if rule == "column":
        return "the rest column"
    if rule == "rolling":
        window = (f"{rest['window_rows']} rows" if "window_rows" in rest
                  else f"{rest['window_s']:g} s")
        return f"the rest followed over {window}"
    return "each file's rest offset"


def live_path(processed_dir: Path, scene: str) -> Path:
    """The frames ``eskin live --record`` kept (no labels: not training data)."""
    return Path(processed_dir) / f"{scene}.live.parquet"
