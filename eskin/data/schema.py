"""The processed dataset: columns, checks, and Parquet with provenance metadata.

One row per sample (docs/data.md):

* the skin's channels (eskin.skin): ``cx1..cxR, cy1..cyC`` for a row/column skin
  (``cx1..cx10, cy1..cy10`` on the paper's), or a channel array's names — float64 (ADC
  counts for acquired data; whatever unit an import carries);
* single force: ``force`` (N), ``x``, ``y`` (0 = no contact, else the node along each
  axis), ``stretch`` (λ);
* two forces: ``force1, x1, y1, force2, x2, y2, stretch``; a recording of their total
  force only: ``force, x1, y1, x2, y2, stretch``, listed in its ``eskin.labels``
  metadata (the kind's total-force variant, eskin.kinds);
* provenance: ``session``, ``trial`` (one condition), ``sample`` (index in
  the trial), ``seq``, ``t_ms`` (board counters; null for imports).

Key-value metadata under ``eskin.*`` records the scene, the plan, the
device, the simulator and its seed, the source file's checksum, and the skin
(``eskin.skin``) when it is not the paper's: a dataset without it is read as the
row/column skin its ``cx``/``cy`` columns spell, so the paper's datasets keep their bytes.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from eskin.errors import EskinError
from eskin.kinds import DATASET_KINDS, Kind, get_kind, kind_of_labels
from eskin.skin import PAPER_SKIN, AnySkin, skin_from_dict, skin_of_columns

LABELS = {name: kind.labels for name, kind in DATASET_KINDS.items()}
PROVENANCE = ["session", "trial", "sample", "seq", "t_ms"]
SCHEMA_VERSION = "1"


class DatasetError(EskinError, ValueError):
    """A dataset that breaks the schema; the message says where."""


def columns(kind: str, skin: AnySkin = PAPER_SKIN) -> list[str]:
    return skin.channels + LABELS[kind] + PROVENANCE


def arrow_schema(kind: str, skin: AnySkin = PAPER_SKIN) -> pa.Schema:
    fields = [pa.field(c, pa.float64(), nullable=False) for c in skin.channels]
    for label in LABELS[kind]:
        kind_of = pa.int64() if label in node_columns(kind) else pa.float64()
        fields.append(pa.field(label, kind_of, nullable=False))
    fields += [pa.field("session", pa.string(), nullable=False),
               pa.field("trial", pa.string(), nullable=False),
               pa.field("sample", pa.int64(), nullable=False),
               pa.field("seq", pa.int64()),
               pa.field("t_ms", pa.int64())]
    return pa.schema(fields)


def node_columns(kind: str) -> list[str]:
    return get_kind(kind).node_columns


def force_columns(kind: str) -> list[str]:
    return get_kind(kind).force_columns


def row_problems(frame: pd.DataFrame, kind: str, skin: AnySkin = PAPER_SKIN) -> pd.Series:
    """Per row, the first reason it cannot be trusted ('' when it can)."""
    checks: list[tuple[np.ndarray, str]] = []
    for column in skin.channels + LABELS[kind]:
        values = frame[column].to_numpy(dtype=float)
        checks += [(np.isnan(values), f"{column} is NaN or empty"),
                   (np.isinf(values), f"{column} is infinite")]
    for column in node_columns(kind):
        values = frame[column].to_numpy(dtype=float)
        top = skin.size_x if column.startswith("x") else skin.size_y
        checks.append(((values < 0) | (values > top) | (values != np.round(values)),
                       f"{column} is not a node number 0..{top}"))
    for column in force_columns(kind):
        checks.append((frame[column].to_numpy(dtype=float) < 0, f"{column} is negative"))
    checks.append((frame["stretch"].to_numpy(dtype=float) <= 0, "stretch is not positive"))
    return first_reason(checks, frame.index)


def first_reason(checks: list[tuple[np.ndarray, str]], index: pd.Index) -> pd.Series:
    """Per row, the reason of the first check that flags it ('' if none does)."""
    masks = np.vstack([mask for mask, _ in checks])
    reasons = np.array(["", *(reason for _, reason in checks)], dtype=object)
    # NaN compares false everywhere above, so a NaN node or force keeps the NaN reason.
    return pd.Series(reasons[np.where(masks.any(axis=0), masks.argmax(axis=0) + 1, 0)],
                     index=index, dtype=object)


def validate(frame: pd.DataFrame, kind: str, where: str = "dataset",
             skin: AnySkin = PAPER_SKIN) -> None:
    """Raise DatasetError naming the first bad column or row."""
    missing = [c for c in columns(kind, skin) if c not in frame.columns]
    if missing:
        raise DatasetError(f"{where}: missing column(s) {missing}")
    reasons = row_problems(frame, kind, skin)
    bad = reasons[reasons != ""]
    if len(bad):
        raise DatasetError(f"{where}: {len(bad)} bad row(s); first at row {bad.index[0]}: "
                           f"{bad.iloc[0]}")
    keys = frame[["session", "trial", "sample"]]
    if keys.duplicated().any():
        first = keys[keys.duplicated()].iloc[0].tolist()
        raise DatasetError(f"{where}: duplicate (session, trial, sample) {first}")


def contact_mask(frame: pd.DataFrame) -> np.ndarray:
    """True where an indenter presses the skin (force > 0 and node > 0): either one,
    in a two-force scene (the total force and either node, where only the total is
    labelled)."""
    return contact_count(frame) > 0


def contact_count(frame: pd.DataFrame) -> np.ndarray:
    """How many indenters press the skin in each row: those with force > 0 and node > 0
    (where only the total force is labelled, the nodes of a row whose total is > 0)."""
    if "x" in frame:
        return ((frame["force"] > 0) & (frame["x"] > 0)).to_numpy().astype(np.int64)
    contacts = range(1, sum(1 for name in frame.columns if name.startswith("x")
                            and name[1:].isdigit()) + 1)
    if "force" in frame:
        nodes = sum((frame[f"x{i}"] > 0).to_numpy().astype(np.int64) for i in contacts)
        return np.where(frame["force"].to_numpy() > 0, nodes, 0)
    return sum((((frame[f"force{i}"] > 0) & (frame[f"x{i}"] > 0)).to_numpy().astype(np.int64)
                for i in contacts), np.zeros(len(frame), dtype=np.int64))


def md5_file(path: Path) -> str:
    """The md5 DVC records for a file output (its bytes' md5), so MLflow and DVC agree."""
    digest = hashlib.md5(usedforsecurity=False)
    with Path(path).open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with Path(path).open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def with_metadata(schema: pa.Schema, metadata: dict) -> pa.Schema:
    """``schema`` carrying ``metadata`` as ``eskin.*`` keys (JSON values)."""
    extra = {f"eskin.{k}": json.dumps(v, sort_keys=True) for k, v in metadata.items()}
    extra["eskin.schema_version"] = SCHEMA_VERSION
    return schema.with_metadata({**(schema.metadata or {}),
                                 **{k.encode(): v.encode() for k, v in extra.items()}})


def skin_metadata(skin: AnySkin) -> dict:
    """The ``eskin.skin`` entry a dataset on ``skin`` carries: none for the paper's skin
    (whose datasets predate it, byte for byte), the skin's declaration otherwise."""
    return {} if skin == PAPER_SKIN else {"skin": skin.as_dict()}


def labels_metadata(kind: Kind) -> dict:
    """The ``eskin.labels`` entry a dataset of ``kind`` carries: none where the labels are
    its scene kind's (so the paper's datasets keep their bytes), the label columns where
    they are a variant's (the total force of several contacts)."""
    return {} if kind.labels == get_kind(kind.scene_kind).labels else {"labels": kind.labels}


def write_dataset(frame: pd.DataFrame, kind: str, path: Path, metadata: dict,
                  skin: AnySkin = PAPER_SKIN) -> None:
    """Validate, then write Parquet with ``eskin.*`` metadata (the skin's and the labels'
    among them), atomically. ``kind``: the dataset's kind (:func:`dataset_kind`)."""
    validate(frame, kind, where=str(path), skin=skin)
    metadata = {**{k: v for k, v in metadata.items() if k not in ("skin", "labels")},
                **skin_metadata(skin), **labels_metadata(get_kind(kind))}
    table = pa.Table.from_pandas(frame[columns(kind, skin)], schema=arrow_schema(kind, skin),
                                 preserve_index=False)
    table = table.replace_schema_metadata(with_metadata(table.schema, metadata).metadata)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(path.suffix + ".partial")
    pq.write_table(table, partial)
    os.replace(partial, path)


def read_metadata(path: Path) -> dict:
    """The ``eskin.*`` metadata of a dataset, decoded."""
    raw = pq.read_schema(path).metadata or {}
    return {k.decode()[len("eskin."):]: json.loads(v) for k, v in raw.items()
            if k.startswith(b"eskin.")}


def read_dataset(path: Path) -> pd.DataFrame:
    return pd.read_parquet(path)


def dataset_skin(path: Path) -> AnySkin:
    """The skin a dataset was taken on: its ``eskin.skin`` metadata, else the row/column
    skin its ``cx``/``cy`` columns spell."""
    meta = read_metadata(path)
    if meta.get("skin"):
        return skin_from_dict(meta["skin"])
    return skin_of_columns(pq.read_schema(path).names)


def dataset_kind(path: Path) -> Kind:
    """The kind of a dataset: its scene's (``eskin.kind``), or that kind's variant its
    ``eskin.labels`` name (the total force of several contacts)."""
    meta = read_metadata(path)
    try:
        return kind_of_labels(meta["kind"], meta.get("labels"))
    except ValueError as error:
        raise DatasetError(f"{path}: {error}") from None


def write_quarantine(rows: list[dict], path: Path) -> None:
    """Rows that could not be trusted, with where they came from and why (header if none)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    pd.DataFrame(rows, columns=["source", "line", "reason", "text"]).to_csv(path, index=False)


def describe_source(meta: dict) -> str:
    """Where a dataset came from, in one line, from its own metadata: ``simulated (seed
    7)``, ``serial /dev/ttyACM0, device ESKIN-1 firmware 1.0``, ``import lab.csv (sha256
    ab12…)``. Every field may be absent (older or foreign datasets)."""
    source = meta.get("source") or {}
    kind = source.get("kind") or "unknown"
    if kind == "simulated":
        seed = (meta.get("simulator") or {}).get("seed")
        return f"simulated (seed {seed})" if seed is not None else "simulated"
    if kind == "emulated":  # the firmware under simavr, reading the simulated skin
        firmware = (meta.get("device") or {}).get("firmware", "?")
        seed = (meta.get("simulator") or {}).get("seed")
        return f"emulated firmware {firmware} under simavr" + (
            f" (seed {seed})" if seed is not None else "")
    if kind == "serial":
        device = meta.get("device") or {}
        parts = [source.get("port") or "port unknown"]
        if device.get("id"):
            parts.append(f"device {device['id']} firmware {device.get('firmware', '?')}")
        return "serial " + ", ".join(parts)
    if kind == "import":
        digest = source.get("sha256") or ""
        where = source.get("imported_from") or source.get("path", "?")
        return f"import {where} (sha256 {digest[:12]}…)"
    return kind
