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

import codecs
import csv
import io
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from eskin.data.ingest import Ingested, check_policy
from eskin.data.schema import (
    CHANNELS,
    LABELS,
    SKIN,
    DatasetError,
    arrow_schema,
    columns,
    first_reason,
    node_columns,
    row_problems,
    sha256_file,
    with_metadata,
)
from eskin.kinds import KINDS, get_kind

WIDTHS = {name: kind.file_widths(SKIN) for name, kind in KINDS.items()}
CHUNK_ROWS = 20_000  # rows held at once: memory is a few chunks, whatever the file's size


def import_paper_layout(path: Path, kind: str, *, bad_rows: str = "error",
                        scene: str | None = None) -> Ingested:
    """Read a CSV or Parquet file in the paper's layout into the dataset schema, in memory
    (tests, fuzzing, small files); :func:`import_to_dataset` streams to Parquet."""
    with tempfile.TemporaryDirectory(prefix="eskin-import-") as scratch:
        out = Path(scratch) / "dataset.parquet"
        quarantine, metadata = import_to_dataset(path, kind, out, bad_rows=bad_rows,
                                                 scene=scene)
        frame = pd.read_parquet(out)
    for column in ("seq", "t_ms"):
        frame[column] = frame[column].astype("Int64")
    return Ingested(frame, metadata, quarantine)


def import_to_dataset(path: Path, kind: str, out: Path, *, bad_rows: str = "error",
                      scene: str | None = None, imported_from: str | None = None
                      ) -> tuple[list[dict], dict]:
    """Stream ``path`` into the dataset file ``out``: (quarantined rows, metadata).
    ``imported_from``: the file ``path`` is a verbatim copy of (the user's own).

    Two passes of ``CHUNK_ROWS`` rows each, so memory stays a few chunks: the first
    judges every row and finds copies of earlier rows (by a 64-bit hash per row),
    the second writes the good rows as Parquet row groups.
    """
    check_policy(bad_rows)
    path = Path(path)
    layout = _layout(path, kind)
    digest = sha256_file(path)
    # Pass 1: reasons and row hashes; copies found by sorting the hashes.
    hashes, hash_lines, bad_count, first_bad, rows_in_file = [], [], 0, None, 0
    for chunk in _judged_chunks(path, layout, {}):
        rows_in_file += len(chunk.lines)
        bad = chunk.reasons != ""
        bad_count += int(bad.sum())
        if first_bad is None and bad.any():
            i = int(np.argmax(bad))
            first_bad = (int(chunk.lines[i]), chunk.reasons[i])
        hashes.append(chunk.hashes[~bad])
        hash_lines.append(chunk.lines[~bad])
    copies = _copies(np.concatenate(hashes) if hashes else np.empty(0, np.uint64),
                     np.concatenate(hash_lines) if hash_lines else np.empty(0, np.int64))
    del hashes, hash_lines
    if copies:
        bad_count += len(copies)
        line, first = min(copies.items())
        if first_bad is None or line < first_bad[0]:
            first_bad = (line, f"duplicate of line {first} (every column equal)")
    if bad_count and bad_rows == "error":
        raise DatasetError(f"{path}:{first_bad[0]}: {first_bad[1]} ({bad_count} bad "
                           "row(s) in all). Set ingest.bad_rows: quarantine to set them aside.")
    # Pass 2: write, the provenance in the footer from the start.
    metadata = {"scene": scene or kind, "kind": kind, "plan": None,
                "device": None, "simulator": None,
                "source": {"kind": "import", "path": str(path), "sha256": digest,
                           "imported_from": imported_from or str(path),
                           "rows_in_file": rows_in_file, "rows_quarantined": bad_count,
                           "stretch_assumed": "stretch" not in layout.labels}}
    session = f"import-{digest[:10]}"
    schema = with_metadata(arrow_schema(kind), metadata)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = out.with_suffix(out.suffix + ".partial")
    quarantine: list[dict] = []
    trials = _TrialCounter(session, LABELS[kind])
    rows_seen = rows_kept = 0
    with pq.ParquetWriter(partial, schema) as writer:
        for chunk in _judged_chunks(path, layout, copies):
            bad = chunk.reasons != ""
            for i in np.flatnonzero(bad):
                quarantine.append({"source": str(path), "line": int(chunk.lines[i]),
                                   "reason": chunk.reasons[i], "text": chunk.text(i)})
            good = chunk.numeric[~bad].reset_index(drop=True)
            for column in node_columns(kind):
                good[column] = good[column].astype(np.int64)
            good["session"] = session
            good["trial"], good["sample"] = trials.label(good)
            good["seq"] = (rows_seen + np.flatnonzero(~bad)).astype(np.int64)
            good["t_ms"] = pd.array([None] * len(good), dtype="Int64")
            rows_seen += len(bad)
            rows_kept += len(good)
            if len(good):
                writer.write_table(pa.Table.from_pandas(good[columns(kind)], schema=schema,
                                                        preserve_index=False))
    if rows_kept == 0:
        partial.unlink()
        raise DatasetError(f"{path}: no usable rows ({rows_in_file} data row(s), all set "
                           "aside; see the quarantine file)")
    os.replace(partial, out)
    return quarantine, metadata


@dataclass
class _Layout:
    kind: str
    parquet: bool
    width: int
    labels: list[str]
    dialect: object = None
    has_header: bool = False


@dataclass
class _Chunk:
    cells: pd.DataFrame      # as read (text for CSV)
    numeric: pd.DataFrame    # named columns, floats (stretch added if the file has none)
    lines: np.ndarray        # file line (CSV) or row index (Parquet) of each row
    reasons: np.ndarray      # '' or why the row cannot be trusted
    hashes: np.ndarray       # 64-bit hash of each row's values

    def text(self, i: int) -> str:
        return ",".join("" if pd.isna(v) else str(v) for v in self.cells.iloc[i].tolist())


class _TrialCounter:
    """A run of consecutive rows with identical labels is one trial, across chunks."""

    def __init__(self, session: str, labels: list[str]) -> None:
        self.session, self.labels = session, labels
        self.trial, self.sample, self.last = -1, 0, None  # carried from chunk to chunk

    def label(self, good: pd.DataFrame) -> tuple[list[str], np.ndarray]:
        values = good[self.labels].to_numpy(dtype=float)
        if not len(values):
            return [], np.empty(0, np.int64)
        before = values[:1] * np.nan if self.last is None else self.last[None, :]
        starts = (values != np.vstack([before, values[:-1]])).any(axis=1)  # a new trial
        trial_of = self.trial + np.cumsum(starts)
        index = np.arange(len(values))
        # Samples count from the last trial start; a trial running on from the last
        # chunk counts on from where it was.
        last_start = np.maximum.accumulate(np.where(starts, index, -1))
        sample_of = np.where(last_start >= 0, index - last_start, self.sample + index)
        self.trial, self.last = int(trial_of[-1]), values[-1]
        self.sample = int(sample_of[-1]) + 1
        names = [f"{self.session}-t{t:05d}" for t in trial_of]
        return names, sample_of.astype(np.int64)


def _copies(hashes: np.ndarray, lines: np.ndarray) -> dict[int, int]:
    """{line of a copy: line of the row it repeats}: equal 64-bit hashes of every value."""
    if len(hashes) < 2:
        return {}
    order = np.lexsort((lines, hashes))
    ordered = hashes[order]
    repeat = np.flatnonzero(ordered[1:] == ordered[:-1]) + 1
    if not len(repeat):
        return {}
    starts = np.flatnonzero(np.r_[True, ordered[1:] != ordered[:-1]])
    first_of_group = starts[np.searchsorted(starts, repeat, side="right") - 1]
    return {int(lines[order[i]]): int(lines[order[f]])
            for i, f in zip(repeat, first_of_group, strict=True)}


def _layout(path: Path, kind: str) -> _Layout:
    """Check what can be checked before reading rows: the file is there, readable, of
    the scene's width, and its header (if any) names the columns where they belong."""
    if not path.exists():
        raise DatasetError(f"{path}: import file not found")
    if path.is_dir():
        raise DatasetError(f"{path}: is a directory, not an import file")
    if path.stat().st_size == 0:
        raise DatasetError(f"{path}: file is empty")
    if path.suffix.lower() == ".parquet":
        try:
            width = len(pq.read_schema(path))
        except (pa.ArrowException, OSError) as err:
            raise DatasetError(f"{path}: not a readable Parquet file ({err})") from err
        layout = _Layout(kind, True, width, [])
    else:
        _check_text(path)
        with _open_text(path) as handle:
            sample = handle.read(65536)
        try:
            dialect = csv.Sniffer().sniff(sample[:4096], delimiters=",;\t")
        except csv.Error:
            dialect = csv.excel
        rows = [r for r in csv.reader(io.StringIO(sample, newline=None), dialect)
                if any(c.strip() for c in r)]
        complete = rows[:-1] if len(sample) == 65536 and len(rows) > 1 else rows
        header = bool(complete) and bool(
            pd.to_numeric(pd.Series(complete[0]), errors="coerce").isna().any())
        data = complete[1:] if header else complete
        if not data:
            raise DatasetError(f"{path}: no data rows")
        lengths = [len(r) for r in data]
        width = max(set(lengths), key=lengths.count)  # the file's width: most rows agree
        layout = _Layout(kind, False, width, [], dialect, header)
    layout.labels = _labels(kind, layout.width, path)
    if layout.has_header:
        _check_header(path, (1, complete[0]), CHANNELS + layout.labels)
    return layout


def _labels(kind: str, width: int, path: Path) -> list[str]:
    if width not in WIDTHS[kind]:
        other = next((k for k, w in WIDTHS.items() if width in w), None)
        hint = f" — that is the {other} layout" if other and other != kind else ""
        raise DatasetError(f"{path}: {width} columns, but the {kind} layout has "
                           f"{' or '.join(map(str, WIDTHS[kind]))}{hint}")
    return get_kind(kind).file_labels(width, SKIN)


def _check_text(path: Path) -> None:
    """UTF-8 without NUL bytes, checked streaming; an error names the line and byte."""
    decoder = codecs.getincrementaldecoder("utf-8")()
    offset = lines = 0
    with path.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            try:
                decoder.decode(block)
            except UnicodeDecodeError as err:
                at = max(0, err.start - len(decoder.getstate()[0]))
                bad = offset + at
                line = lines + block[:at].count(b"\n") + 1
                raise DatasetError(f"{path}:{line}: not UTF-8 text (byte {bad}: "
                                   f"{block[at:at + 1]!r}); save the file as UTF-8 CSV"
                                   ) from None
            if b"\x00" in block:
                raise DatasetError(f"{path}: contains NUL bytes; is it a CSV file?")
            offset += len(block)
            lines += block.count(b"\n")
        try:
            decoder.decode(b"", final=True)
        except UnicodeDecodeError:
            raise DatasetError(f"{path}:{lines + 1}: not UTF-8 text (the file ends inside a "
                               "character); save the file as UTF-8 CSV") from None


def _open_text(path: Path):
    # Universal newlines: a lone CR ends a line too (old Mac files, stray bytes).
    return path.open(encoding="utf-8-sig", newline=None)


def _raw_chunks(path: Path, layout: _Layout):
    """(cells, line numbers, preset reasons) per ``CHUNK_ROWS`` rows."""
    if layout.parquet:
        try:
            batches = pq.ParquetFile(path).iter_batches(batch_size=CHUNK_ROWS)
            start = 0
            for batch in batches:
                cells = batch.to_pandas()
                cells.columns = range(cells.shape[1])
                # A Parquet row's "line" is its 0-based row index.
                yield (cells, np.arange(start, start + len(cells)),
                       np.full(len(cells), "", dtype=object))
                start += len(cells)
        except (pa.ArrowException, OSError) as err:
            raise DatasetError(f"{path}: not a readable Parquet file ({err})") from err
        return
    width = layout.width
    with _open_text(path) as handle:
        reader = csv.reader(handle, layout.dialect)
        skip_header = layout.has_header
        rows, numbers = [], []
        try:
            for row in reader:
                if not any(c.strip() for c in row):
                    continue
                if skip_header:
                    skip_header = False
                    continue
                rows.append(row)
                numbers.append(reader.line_num)
                if len(rows) == CHUNK_ROWS:
                    yield _cells(rows, numbers, width)
                    rows, numbers = [], []
        except csv.Error as err:
            raise DatasetError(f"{path}:{reader.line_num}: not readable as CSV ({err})"
                               ) from None
        if rows:
            yield _cells(rows, numbers, width)


def _cells(rows: list[list[str]], numbers: list[int], width: int):
    cells = pd.DataFrame([(r + [""] * width)[:width] for r in rows])  # "" converts to NaN
    reasons = np.array(["" if len(r) == width else
                        f"row has {len(r)} columns, expected {width}{_layout_hint(len(r))}"
                        for r in rows], dtype=object)
    return cells, np.array(numbers, dtype=np.int64), reasons


def _judged_chunks(path: Path, layout: _Layout, copies: dict[int, int]):
    kind, names = layout.kind, CHANNELS + layout.labels
    for cells, lines, reasons in _raw_chunks(path, layout):
        if cells.shape[1] != layout.width:  # a Parquet file's width is its schema's
            raise DatasetError(f"{path}: {cells.shape[1]} columns, expected {layout.width}")
        frame = cells.set_axis(names, axis=1)
        numeric = frame.apply(pd.to_numeric, errors="coerce").astype(float)
        # Text where a number belongs (empty and "nan" are NaN, judged below); only the
        # cells that did not convert are looked at, one by one.
        missing = numeric[names].isna().to_numpy()
        text_cell = np.zeros_like(missing)
        if missing.any():
            rows, cols = np.nonzero(missing)
            text_cell[rows, cols] = ~_blank(frame.to_numpy(dtype=object)[rows, cols]
                                            ).astype(bool)
        text = first_reason([(text_cell[:, j], f"{c} is not a number")
                             for j, c in enumerate(names)], frame.index).to_numpy()
        reasons = np.where(reasons == "", text, reasons)
        if "stretch" not in numeric:
            numeric["stretch"] = 1.0
        more = row_problems(numeric, kind).to_numpy()
        reasons = np.where(reasons == "", more, reasons)
        if copies:
            for i in np.flatnonzero(np.isin(lines, list(copies)) & (reasons == "")):
                reasons[i] = f"duplicate of line {copies[int(lines[i])]} (every column equal)"
        hashes = pd.util.hash_pandas_object(numeric[names], index=False).to_numpy()
        yield _Chunk(cells, numeric, lines, reasons.astype(object), hashes)


# A cell that holds no value: missing, empty or "nan" (NaN, not text).
_blank = np.frompyfunc(
    lambda v: v is None or (isinstance(v, float) and v != v)
    or (isinstance(v, str) and v.strip().lower() in ("", "nan")), 1, 1)


def _layout_hint(width: int) -> str:
    other = next((kind for kind, widths in WIDTHS.items() if width in widths), None)
    return f" (a {other} row: scenes mixed in one file?)" if other else ""


def _normalise(name: str) -> str:
    """``Force (N)`` → ``force``, ``C_X 1`` → ``cx1``, ``λ`` → ``lambda``."""
    name = name.strip().lower().split("(")[0].split("[")[0]
    name = "".join(ch for ch in name if ch.isalnum() or ch == "λ")
    return name.replace("λ", "lambda")


def header_names(expected: list[str]) -> list[set[str]]:
    """Per column of a layout, the names a lab's header may give it (normalised): ours,
    the paper's (x1..x10, y1..y10 for the terminals), numbered channels (c1..c20,
    ch1, channel1), and common label spellings (f, load, lambda, node_x)."""
    out = []
    for position, ours in enumerate(expected):
        names = {ours}
        if position < len(CHANNELS):
            number = position + 1
            axis, index = ours[1], ours[2:]   # cx3 → x, 3
            names |= {f"{axis}{index}", f"c{axis}{index}", f"{axis}ch{index}",
                      *(f"{p}{number}" for p in ("c", "ch", "channel", "cap", "s"))}
        else:
            contact = ours[-1] if ours[-1].isdigit() else ""
            base = ours.rstrip("12")
            spellings = {"force": ["force", "f", "load", "forcen", "fn", "fz"],
                         "x": ["x", "nodex", "xnode", "posx", "row", "i"],
                         "y": ["y", "nodey", "ynode", "posy", "col", "column", "j"],
                         "stretch": ["stretch", "lambda", "stretchratio", "l"]}[base]
            names |= {f"{name}{contact}" for name in spellings}  # F_1 normalises to f1
        out.append(names)
    return out


def _check_header(path: Path, header: tuple[int, list[str]], expected: list[str]) -> None:
    """A header may name the columns its own way (:func:`header_names`); one that names
    a column of the layout somewhere else is refused, saying what to rename."""
    line, names = header
    accepted = header_names(expected)
    elsewhere = {name: i for i, names_at in enumerate(accepted) for name in names_at}
    for position, raw in enumerate(names):
        name = _normalise(raw)
        if position < len(accepted) and name in accepted[position]:
            continue
        if name in elsewhere and elsewhere[name] != position:
            where = (f"where the layout has {expected[position]!r}" if position < len(expected)
                     else "beyond the layout's columns")
            raise DatasetError(
                f"{path}:{line}: the header has {raw.strip()!r} in column {position + 1}, "
                f"{where} ({raw.strip()!r} names column {elsewhere[name] + 1}, "
                f"{expected[elsewhere[name]]!r}); rename it, or put the columns in the "
                f"paper's order: 20 terminals, then {', '.join(expected[20:])}")


def check_layout(path: Path, kind: str) -> None:
    """What can be judged of an import file without reading its rows (existence, width,
    header, encoding of the first 64 KiB): a DatasetError naming the file, else None."""
    _layout(Path(path), kind)


def copy_import(source: Path, raw_dir: Path, kind: str) -> Path:
    """Check an import file's layout, then keep a verbatim copy under ``raw_dir``
    (DVC versions it from there); rows are judged at ingest."""
    source = Path(source)
    _layout(source, kind)
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
