"""Import external data in the paper's layout as a dataset.

Layouts (one row per sample, optional header row):

* single force — 20 capacitance columns, then force, x, y, stretch (24);
* two forces — 20, then force1, x1, y1, force2, x2, y2 (26), optionally
  stretch (27); without it λ = 1, the paper's two-force protocol.

Trials: the paper's data come in blocks of samples under one condition, so a
run of consecutive rows with identical labels is one trial and ``sample``
counts within it. ``seq`` is the data row's index, ``t_ms`` is null.

Whole-file problems (unreadable, empty, wrong encoding, wrong column count,
a header that names our columns in other places, a truncated Parquet) are
errors. Row problems (text in a numeric column, NaN or inf, a node outside
0..10, a negative force, a short row or one of another scene's width, a copy
of an earlier row) are errors naming file, line and column, or, under
``bad_rows: quarantine``, rows set aside with their reason and counted.
"""

from __future__ import annotations

import csv
import io
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from eskin.data.ingest import Ingested, check_policy
from eskin.data.schema import (
    CHANNELS,
    LABELS,
    DatasetError,
    first_reason,
    node_columns,
    row_problems,
    sha256_file,
)

WIDTHS = {"single_force": (24,), "two_force": (26, 27)}


def import_paper_layout(path: Path, kind: str, *, bad_rows: str = "error",
                        scene: str | None = None) -> Ingested:
    """Read a CSV or Parquet file in the paper's layout into the dataset schema."""
    check_policy(bad_rows)
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"{path}: import file not found")
    if path.stat().st_size == 0:
        raise DatasetError(f"{path}: file is empty")
    if path.suffix.lower() == ".parquet":
        cells, lines, reasons = _read_parquet(path)
        header = None
    else:
        cells, lines, reasons, header = _read_csv(path)
    width = cells.shape[1]
    if width not in WIDTHS[kind]:
        other = next((k for k, w in WIDTHS.items() if width in w), None)
        hint = f" — that is the {other} layout" if other and other != kind else ""
        raise DatasetError(f"{path}: {width} columns, but the {kind} layout has "
                           f"{' or '.join(map(str, WIDTHS[kind]))}{hint}")
    labels = LABELS[kind] if width > 26 or kind == "single_force" else LABELS[kind][:-1]
    if header is not None:
        _check_header(path, header, CHANNELS + labels)
    frame = cells.set_axis(CHANNELS + labels, axis=1)
    numeric = frame.apply(pd.to_numeric, errors="coerce")
    # Text where a number belongs (empty and "nan" are NaN, judged later).
    blank = _blank(frame.to_numpy(dtype=object)).astype(bool)
    text = first_reason([(numeric[c].isna().to_numpy() & ~blank[:, j], f"{c} is not a number")
                         for j, c in enumerate(frame.columns)], frame.index)
    reasons[reasons == ""] = text[reasons == ""]
    if "stretch" not in numeric:
        numeric["stretch"] = 1.0
    more = row_problems(numeric, kind)
    reasons[reasons == ""] = more[reasons == ""]
    # A row equal to an earlier one in every column is a pasted copy, not a new sample
    # (readings carry noise); the first copy is kept.
    values = numeric[CHANNELS + labels]
    copies = values.duplicated(keep="first").to_numpy() & (reasons == "").to_numpy()
    if copies.any():
        first = pd.Series(np.arange(len(values))).groupby(
            pd.util.hash_pandas_object(values, index=False).to_numpy()).transform("min")
        reasons[copies] = [f"duplicate of line {lines[i]} (every column equal)"
                           for i in first.to_numpy()[copies]]
    bad = reasons != ""
    if bad.any() and bad_rows == "error":
        first = bad.idxmax()
        raise DatasetError(f"{path}:{lines[first]}: {reasons[first]} ({int(bad.sum())} bad "
                           "row(s) in all). Set ingest.bad_rows: quarantine to set them aside.")
    quarantine = [{"source": str(path), "line": int(lines[i]), "reason": reasons[i],
                   "text": ",".join(map(str, cells.loc[i].tolist()))} for i in np.flatnonzero(bad)]
    good = numeric[~bad.to_numpy()].reset_index(drop=True)
    digest = sha256_file(path)
    for column in node_columns(kind):
        good[column] = good[column].astype(np.int64)
    label_cols = LABELS[kind]
    changed = good[label_cols].ne(good[label_cols].shift()).any(axis=1)
    trial_index = changed.cumsum() - 1
    session = f"import-{digest[:10]}"
    good["session"] = session
    good["trial"] = [f"{session}-t{t:05d}" for t in trial_index]
    good["sample"] = good.groupby(trial_index).cumcount().astype(np.int64)
    good["seq"] = pd.array(np.flatnonzero(~bad.to_numpy()), dtype="Int64")
    good["t_ms"] = pd.array([None] * len(good), dtype="Int64")
    metadata = {"scene": scene or kind, "kind": kind, "plan": None,
                "device": None, "simulator": None,
                "source": {"kind": "import", "path": str(path), "sha256": digest,
                           "rows_in_file": len(frame), "rows_quarantined": int(bad.sum()),
                           "stretch_assumed": "stretch" not in labels}}
    return Ingested(good, metadata, quarantine)


Read = tuple[pd.DataFrame, np.ndarray, pd.Series]  # cells, line numbers, preset reasons

# A cell that holds no value: missing, empty or "nan" (NaN, not text).
_blank = np.frompyfunc(
    lambda v: v is None or (isinstance(v, float) and v != v)
    or (isinstance(v, str) and v.strip().lower() in ("", "nan")), 1, 1)


def _read_parquet(path: Path) -> Read:
    try:
        table = pq.read_table(path)
    except (pa.ArrowException, OSError) as err:
        raise DatasetError(f"{path}: not a readable Parquet file ({err})") from err
    frame = table.to_pandas()
    frame.columns = range(frame.shape[1])
    # A Parquet row's "line" is its 0-based row index.
    return frame, np.arange(len(frame)), pd.Series("", index=frame.index, dtype=object)


def _read_csv(path: Path) -> tuple[pd.DataFrame, np.ndarray, pd.Series, tuple | None]:
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        line = raw[: err.start].count(b"\n") + 1
        raise DatasetError(f"{path}:{line}: not UTF-8 text (byte {err.start}: "
                           f"{raw[err.start:err.start + 1]!r}); save the file as UTF-8 CSV"
                           ) from None
    if "\x00" in text:
        raise DatasetError(f"{path}: contains NUL bytes; is it a CSV file?")
    try:
        dialect = csv.Sniffer().sniff(text[:4096], delimiters=",;\t")
    except csv.Error:
        dialect = csv.excel
    # Universal newlines: a lone CR ends a line too (old Mac files, stray bytes).
    reader = csv.reader(io.StringIO(text, newline=None), dialect)
    try:
        rows = [(n, r) for n, r in enumerate(reader, start=1) if any(c.strip() for c in r)]
    except csv.Error as err:
        raise DatasetError(f"{path}:{reader.line_num}: not readable as CSV ({err})") from None
    header = None
    if rows and pd.to_numeric(pd.Series(rows[0][1]), errors="coerce").isna().any():
        header, rows = rows[0], rows[1:]  # a header row
    if not rows:
        raise DatasetError(f"{path}: no data rows")
    lengths = [len(r) for _, r in rows]
    width = max(set(lengths), key=lengths.count)  # the file's width: most rows agree
    cells = pd.DataFrame([(r + [""] * width)[:width] for _, r in rows]).replace("", np.nan)
    reasons = pd.Series(["" if len(r) == width else
                         f"row has {len(r)} columns, expected {width}{_layout_hint(len(r))}"
                         for _, r in rows], dtype=object)
    return cells, np.array([n for n, _ in rows]), reasons, header


def _layout_hint(width: int) -> str:
    other = next((kind for kind, widths in WIDTHS.items() if width in widths), None)
    return f" (a {other} row: scenes mixed in one file?)" if other else ""


def _check_header(path: Path, header: tuple[int, list[str]], expected: list[str]) -> None:
    """A header that names our columns must name them where the layout has them."""
    line, names = header
    known = set(CHANNELS) | {label for labels in LABELS.values() for label in labels}
    for position, name in enumerate(names):
        name = name.strip().lower()
        if name in known and (position >= len(expected) or expected[position] != name):
            where = expected[position] if position < len(expected) else "no column"
            raise DatasetError(f"{path}:{line}: the header has {name!r} in column "
                               f"{position + 1}, where the layout has {where!r}; put the "
                               f"columns in the paper's order ({', '.join(expected[18:])})")


def copy_import(source: Path, raw_dir: Path, kind: str) -> Path:
    """Check an import file's layout, then keep a verbatim copy under ``raw_dir``
    (DVC versions it from there); rows are judged at ingest."""
    source = Path(source)
    import_paper_layout(source, kind, bad_rows="quarantine")
    raw_dir = Path(raw_dir)
    raw_dir.mkdir(parents=True, exist_ok=True)
    for old in raw_dir.glob("import.*"):
        old.unlink()
    target = raw_dir / f"import{source.suffix.lower() or '.csv'}"
    shutil.copyfile(source, target)
    return target


def find_import(raw_dir: Path) -> Path:
    found = sorted(Path(raw_dir).glob("import.*"))
    if not found:
        raise DatasetError(f"{raw_dir}: no imported file; set scenes.<scene>.import_path "
                           "and run the acquire stage")
    return found[0]
