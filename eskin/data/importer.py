"""Import external data as a dataset: a file in the paper's layout, or another
instrument's files through a column map (``scenes.<s>.import``; docs/data.md#importing).

The paper's layout (one row per sample, optional header row), on the scene's skin:

* single force — the skin's channels (20 on the paper's), then force, x, y, stretch;
* two forces — the channels, then force1, x1, y1, force2, x2, y2, optionally
  stretch; without it λ = 1, the paper's two-force protocol.

Its trials: the paper's data come in blocks of samples under one condition, so a run
of consecutive rows with identical labels is one trial and ``sample`` counts within
it. ``seq`` is the data row's index, ``t_ms`` is null. It is streamed.

A column map reads a file, a folder or a glob of them by their headers' names, a file
at a time; the labels are made from the columns (units, sign, each file's rest offset
and a contact rule, positions in mm or from the file's name) and trials come from the
labels, the files, blocks of time or a column.

Whole-file problems (unreadable, empty, wrong encoding, wrong column count, a header
that names our columns in other places or lacks a mapped one, a truncated Parquet) are
errors. Row problems (text in a numeric column, NaN or inf, a node off the skin, a
negative force, a short row or one of another scene's width, a copy of an earlier row)
are errors naming file, line and column, or, under ``bad_rows: quarantine``, rows set
aside with their reason and counted. Dropped frames (every channel 0) and stale repeats
(every channel equal to the row before) are a sensor's hiccups: set aside and counted
under either policy.
"""

from __future__ import annotations

import codecs
import csv
import difflib
import fnmatch
import glob
import hashlib
import io
import itertools
import os
import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from eskin.config.scenes import (
    FORCE_UNITS,
    Import,
    ImportedScene,
    Rest,
    import_kind,
    scene_skin,
)
from eskin.data.ingest import Ingested, check_policy
from eskin.data.schema import (
    LABELS,
    PROVENANCE,
    DatasetError,
    arrow_schema,
    columns,
    contact_mask,
    first_reason,
    labels_metadata,
    node_columns,
    row_problems,
    sha256_file,
    skin_metadata,
    with_metadata,
)
from eskin.kinds import KINDS, get_kind
from eskin.skin import PAPER_SKIN, AnySkin

CHUNK_ROWS = 20_000  # rows held at once: memory is a few chunks, whatever the file's size
# A sensor's hiccups, not a bad file: set aside whatever ingest.bad_rows says, and counted.
DROPPED = "dropped frame (every channel 0)"
STALE = "stale repeat of the row before (every channel equal)"


def import_paper_layout(path: Path, kind: str, *, skin: AnySkin = PAPER_SKIN,
                        bad_rows: str = "error", scene: str | None = None) -> Ingested:
    """Read a CSV or Parquet file in the paper's layout (``skin``'s channels, then the
    labels) into the dataset schema, in memory (tests, fuzzing, small files);
    :func:`import_to_dataset` streams to Parquet."""
    with tempfile.TemporaryDirectory(prefix="eskin-import-") as scratch:
        out = Path(scratch) / "dataset.parquet"
        quarantine, metadata = import_to_dataset(path, kind, out, skin=skin,
                                                 bad_rows=bad_rows, scene=scene)
        frame = pd.read_parquet(out)
    for column in ("seq", "t_ms"):
        frame[column] = frame[column].astype("Int64")
    return Ingested(frame, metadata, quarantine)


def import_to_dataset(path: Path, kind: str, out: Path, *, skin: AnySkin = PAPER_SKIN,
                      bad_rows: str = "error", scene: str | None = None,
                      imported_from: str | None = None) -> tuple[list[dict], dict]:
    """Stream ``path`` (the paper's layout on ``skin``) into the dataset file ``out``:
    (quarantined rows, metadata). ``imported_from``: the file ``path`` is a verbatim copy
    of (the user's own).

    Two passes of ``CHUNK_ROWS`` rows each, so memory stays a few chunks: the first
    judges every row and finds copies of earlier rows (by a 64-bit hash per row),
    the second writes the good rows as Parquet row groups.
    """
    check_policy(bad_rows)
    path = Path(path)
    layout = _layout(path, kind, skin)
    digest = sha256_file(path)
    # Pass 1: reasons and row hashes; copies found by sorting the hashes.
    hashes, hash_lines, bad_count, first_bad, rows_in_file = [], [], 0, None, 0
    set_aside = {DROPPED: 0, STALE: 0}
    for chunk in _judged_chunks(path, layout, {}):
        rows_in_file += len(chunk.lines)
        bad = chunk.reasons != ""
        hiccup = np.isin(chunk.reasons, list(set_aside))
        for reason in set_aside:
            set_aside[reason] += int((chunk.reasons == reason).sum())
        bad_count += int((bad & ~hiccup).sum())
        if first_bad is None and (bad & ~hiccup).any():
            i = int(np.argmax(bad & ~hiccup))
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
                           "rows_in_file": rows_in_file,
                           "rows_quarantined": bad_count + sum(set_aside.values()),
                           "dropped_frames": set_aside[DROPPED],
                           "stale_repeats": set_aside[STALE],
                           "stretch_assumed": "stretch" not in layout.labels},
                **skin_metadata(skin)}
    session = f"import-{digest[:10]}"
    schema = with_metadata(arrow_schema(kind, skin), metadata)
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
                writer.write_table(pa.Table.from_pandas(good[columns(kind, skin)], schema=schema,
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
    skin: AnySkin = PAPER_SKIN
    dialect: object = None
    has_header: bool = False
    header: list[str] | None = None


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


def _layout(path: Path, kind: str, skin: AnySkin) -> _Layout:
    """Check what can be checked before reading rows: the file is there, readable, of
    the scene's width, and its header (if any) names the columns where they belong."""
    layout = _file_layout(path, kind, skin)
    layout.labels = _labels(kind, layout.width, path, skin)
    if layout.has_header:
        _check_header(path, (1, layout.header), skin.channels + layout.labels, skin)
    return layout


def _file_layout(path: Path, kind: str, skin: AnySkin) -> _Layout:
    """A file's format, width and header row (if any), from its first 64 KiB: any
    layout's first look."""
    if not path.exists():
        raise DatasetError(f"{path}: import file not found")
    if path.is_dir():
        raise DatasetError(f"{path}: is a directory, not an import file")
    if path.stat().st_size == 0:
        raise DatasetError(f"{path}: file is empty")
    if path.suffix.lower() == ".parquet":
        try:
            names = pq.read_schema(path).names
        except (pa.ArrowException, OSError) as err:
            raise DatasetError(f"{path}: not a readable Parquet file ({err})") from err
        return _Layout(kind, True, len(names), [], skin, header=names)
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
    return _Layout(kind, False, width, [], skin, dialect, header,
                   complete[0] if header else None)


def _widths(skin: AnySkin) -> dict[str, tuple[int, ...]]:
    """The column counts of each kind's file in the paper's layout on ``skin``."""
    return {name: kind.file_widths(skin) for name, kind in KINDS.items()}


def _labels(kind: str, width: int, path: Path, skin: AnySkin) -> list[str]:
    widths = _widths(skin)
    if width not in widths[kind]:
        other = next((k for k, w in widths.items() if width in w), None)
        hint = f" — that is the {other} layout" if other and other != kind else ""
        raise DatasetError(f"{path}: {width} columns, but the {kind} layout has "
                           f"{' or '.join(map(str, widths[kind]))}{hint} (the skin's "
                           f"{skin.terminals} channels, then "
                           f"{', '.join(get_kind(kind).labels)}); for another instrument's "
                           "files, name their columns in import.columns")
    return get_kind(kind).file_labels(width, skin)


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
                    yield _cells(rows, numbers, layout)
                    rows, numbers = [], []
        except csv.Error as err:
            raise DatasetError(f"{path}:{reader.line_num}: not readable as CSV ({err})"
                               ) from None
        if rows:
            yield _cells(rows, numbers, layout)


def _cells(rows: list[list[str]], numbers: list[int], layout: _Layout):
    width = layout.width
    cells = pd.DataFrame([(r + [""] * width)[:width] for r in rows])  # "" converts to NaN
    reasons = np.array(["" if len(r) == width else
                        f"row has {len(r)} columns, expected {width}{_layout_hint(len(r), layout)}"
                        for r in rows], dtype=object)
    return cells, np.array(numbers, dtype=np.int64), reasons


def _judged_chunks(path: Path, layout: _Layout, copies: dict[int, int]):
    kind, skin = layout.kind, layout.skin
    names = skin.channels + layout.labels
    previous = np.full((1, skin.terminals), np.nan)  # the row before, across chunks
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
        hiccups, previous = _hiccups(numeric[skin.channels].to_numpy(), previous)
        reasons = np.where(hiccups != "", hiccups, reasons)
        if "stretch" not in numeric:
            numeric["stretch"] = 1.0
        more = row_problems(numeric, kind, skin).to_numpy()
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


def _hiccups(channels: np.ndarray, previous: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row, DROPPED, STALE or ''; and the last row, the next chunk's row before.
    A stale repeat is a sensor sending its last frame again: equal to the row just before
    (a copy of an earlier row is another matter: an error)."""
    before = np.vstack([previous, channels[:-1]])
    dropped = (channels == 0).all(axis=1)
    stale = ~dropped & (channels == before).all(axis=1)
    reasons = np.where(dropped, DROPPED, np.where(stale, STALE, "")).astype(object)
    return reasons, channels[-1:] if len(channels) else previous


def _layout_hint(width: int, layout: _Layout) -> str:
    if not layout.labels:  # a column map: widths say nothing of the kind
        return ""
    other = next((kind for kind, widths in _widths(layout.skin).items() if width in widths),
                 None)
    return f" (a {other} row: scenes mixed in one file?)" if other else ""


def _normalise(name: str) -> str:
    """``Force (N)`` → ``force``, ``C_X 1`` → ``cx1``, ``λ`` → ``lambda``."""
    name = name.strip().lower().split("(")[0].split("[")[0]
    name = "".join(ch for ch in name if ch.isalnum() or ch == "λ")
    return name.replace("λ", "lambda")


def header_names(expected: list[str], skin: AnySkin = PAPER_SKIN) -> list[set[str]]:
    """Per column of a layout, the names a lab's header may give it (normalised): ours,
    the paper's (x1..x10, y1..y10 for the terminals of a row/column skin), numbered
    channels (c1..c20, ch1, channel1), and common label spellings (f, load, lambda,
    node_x)."""
    out = []
    for position, ours in enumerate(expected):
        names = {_normalise(ours)}
        if position < skin.terminals:
            number = position + 1
            names |= {f"{p}{number}" for p in ("c", "ch", "channel", "cap", "s")}
            if skin.row_column:
                axis, index = ours[1], ours[2:]   # cx3 → x, 3
                names |= {f"{axis}{index}", f"c{axis}{index}", f"{axis}ch{index}"}
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


def _check_header(path: Path, header: tuple[int, list[str]], expected: list[str],
                  skin: AnySkin) -> None:
    """A header may name the columns its own way (:func:`header_names`); one that names
    a column of the layout somewhere else is refused, saying what to rename."""
    line, names = header
    accepted = header_names(expected, skin)
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
                f"paper's order: {skin.terminals} channels, then "
                f"{', '.join(expected[skin.terminals:])}")


# ---------------------------------------------------------------- a scene's files

_TABLES = (".csv", ".parquet")


def import_files(name: str, spec: Import) -> list[Path]:
    """The files ``scenes.<name>.import.path`` names — a file, a folder (its CSV and
    Parquet files) or a glob — in sorted order of their names; one line naming the key
    when there are none or the scene cannot take them."""
    key = f"scenes.{name}.import.path = {spec.path!r}"
    path = Path(spec.path)
    if glob.has_magic(spec.path):
        found = [Path(p) for p in glob.glob(spec.path, recursive=True) if Path(p).is_file()]
        if not found:
            raise DatasetError(f"{key}: matches no file")
    elif path.is_dir():
        found = [p for p in path.iterdir() if p.is_file() and p.suffix.lower() in _TABLES]
        if not found:
            raise DatasetError(f"{key}: the folder has no CSV or Parquet file")
    elif path.exists():
        found = [path]
    else:
        raise DatasetError(f"{key}: no such file")
    found.sort(key=lambda p: p.name)
    if spec.columns is None and len(found) > 1:
        raise DatasetError(f"{key}: {len(found)} files, but a file in the paper's layout is "
                           "one per scene; name one, or map the files' columns with "
                           "import.columns")
    twice = [a.name for a, b in itertools.pairwise(found) if a.name == b.name]
    if twice:
        raise DatasetError(f"{key}: two files are called {twice[0]!r}; the copy under "
                           "data/raw/ keeps names, so they must differ")
    for file in found:
        try:
            with file.open("rb") as handle:
                handle.read(1)
        except OSError as err:
            raise DatasetError(f"{key}: {file} cannot be read ({err.strerror})") from None
    return found


def check_import(name: str, scene: ImportedScene) -> None:
    """What can be judged of an import scene's files without reading their rows (they
    exist; width, header, encoding; the columns the map names; the positions their names
    give): one line naming the scene's key and the file, else None."""
    spec, skin = scene.import_, scene_skin(scene)
    for path in import_files(name, spec):
        try:
            if spec.columns is None:
                _layout(path, scene.kind, skin)
            else:
                _column_map(path, spec, scene.kind, skin)
        except DatasetError as err:
            raise DatasetError(f"scenes.{name}.import: {err}") from None


def copy_import(name: str, scene: ImportedScene, raw_dir: Path) -> list[Path]:
    """Check an import scene's files, then keep verbatim copies under
    ``raw_dir/import/`` (DVC versions them from there; names kept, for
    ``position_from_name``); rows are judged at ingest."""
    check_import(name, scene)
    target = Path(raw_dir) / "import"
    if target.exists():
        shutil.rmtree(target)
    target.mkdir(parents=True)
    copies = []
    for source in import_files(name, scene.import_):
        copies.append(target / source.name)
        shutil.copyfile(source, copies[-1])
    return copies


def find_import(raw_dir: Path, name: str) -> list[Path]:
    """The copies of scene ``name``'s files the acquire step kept, in sorted order."""
    folder = Path(raw_dir) / "import"
    found = sorted(folder.iterdir(), key=lambda p: p.name) if folder.is_dir() else []
    if not found:
        raise DatasetError(f"{raw_dir}: no imported file; set scenes.{name}.import.path and "
                           f"run `eskin acquire {name}`")
    return found


# ---------------------------------------------------------------- another instrument's files
#
# A column map (import.columns) reads each file by its header's names, one file at a time:
# memory is one file, not the recording. Labels are made in this order: unit and sign;
# each file's rest offset and the contact rule (import.contact_n); positions (a node, mm
# placed on the skin's grid, or the file's name); the order of two contacts; trials.


@dataclass
class _Judged:
    """One file, read and judged: the dataset's label columns for every row, and why a
    row cannot be kept ('' when it can)."""

    cells: pd.DataFrame       # as read
    lines: np.ndarray         # file line (CSV; the header is line 1) or row index (Parquet)
    channels: np.ndarray      # rows × the skin's channels
    labels: pd.DataFrame      # the dataset's label columns
    reasons: np.ndarray
    at_rest: np.ndarray       # below the contact rule in a scene whose rows all press
    trial: np.ndarray | None  # each row's trial in the file (the trial column's); None:
                              # runs of identical labels, counted over the rows kept
    t_ms: np.ndarray          # float ms (NaN: no time column)
    rest_offset: _RestOffset | None  # None: no contact rule
    hashes: np.ndarray

    def text(self, i: int) -> str:
        return ",".join("" if pd.isna(v) else str(v) for v in self.cells.iloc[i].tolist())


@dataclass(frozen=True)
class _RestOffset:
    """A file's rest as its metadata states it: the median over its usable rows, and the
    range where the rule follows it row by row."""

    median: float
    low: float
    high: float
    varies: bool

    @classmethod
    def of(cls, rest: np.ndarray, spec: Import) -> _RestOffset:
        finite = rest[np.isfinite(rest)]
        if not len(finite):
            return cls(float("nan"), float("nan"), float("nan"), False)
        varies = spec.rest is not None and spec.rest.rule in ("column", "rolling")
        return cls(float(np.median(finite)), float(finite.min()), float(finite.max()), varies)

    def entry(self) -> dict:
        """The file's ``rest_offset_n`` (and ``rest_range_n``) in ``eskin.source.files``."""
        out = {"rest_offset_n": self.median}
        if self.varies:
            out["rest_range_n"] = [self.low, self.high]
        return out


def rest_force(force: np.ndarray, spec: Import, numeric: pd.DataFrame, path: Path
               ) -> np.ndarray:
    """Per row of one file, what its force sensor reads untouched, by ``import.rest``'s
    rule (``force``: the total force of the usable rows, NaN elsewhere; ``numeric``: the
    file's mapped columns, for ``time`` and ``rest``)."""
    rule = spec.rest or Rest()
    contact_n = float(spec.contact_n)
    n = len(force)
    if rule.rule == "low_tail":
        return np.full(n, rest_offset(force, contact_n))
    if rule.rule == "column":
        return numeric["rest"].to_numpy() * FORCE_UNITS[spec.force_unit] * spec.force_sign
    if rule.rule == "first":
        if rule.rows is not None:
            head, what = np.arange(n) < rule.rows, f"first {rule.rows} row(s)"
        else:
            time = numeric["time"].to_numpy()
            start = np.nanmin(time) if np.isfinite(time).any() else np.nan
            head, what = (time - start) < float(rule.seconds), f"first {rule.seconds:g} s"
        tare = force[head & np.isfinite(force)]
        if not len(tare):
            raise DatasetError(f"{path}: no usable row in its {what}, which import.rest.rule: "
                               "first takes as the rest")
        return np.full(n, float(np.median(tare)))
    window = rule.window_rows
    if window is None:
        steps = np.diff(numeric["time"].to_numpy())
        steps = steps[np.isfinite(steps) & (steps > 0)]
        if not len(steps):
            raise DatasetError(f"{path}: its time column does not advance, so "
                               "import.rest.window_s counts no rows; set window_rows")
        window = max(2, round(float(rule.window_s) / float(np.median(steps))))
    return followed_rest(force, window, contact_n,
                         contact_n if rule.below_n is None else float(rule.below_n))


def followed_rest(force: np.ndarray, window: int, contact_n: float, below_n: float
                  ) -> np.ndarray:
    """The rest followed within a file: per row, :func:`rest_offset`'s rule (the median of
    the rows within ``contact_n / 2`` of the 10th percentile) over the ``window`` rows
    up to it and over those from it on; of the two, the larger that the row does not lie
    below by more than ``below_n`` (how far a row at rest may dip). So a press (above
    both) is measured from the rest around it, a dip after a release from the rest it
    dips below, and a rest that steps, up or down, is followed from the side it has
    stepped to. Rows that neither window covers with half its rows take the nearest
    rows' rest."""
    force = np.asarray(force, dtype=float)
    before = _window_rest(force, window, contact_n)
    after = _window_rest(force[::-1], window, contact_n)[::-1]
    both = np.column_stack([before, after])
    with np.errstate(invalid="ignore"):
        eligible = both <= (force + below_n)[:, None]
    chosen = np.fmax(*np.where(eligible, both, np.nan).T)
    rest = np.where(np.isnan(chosen), np.fmax(before, after), chosen)
    if np.isnan(rest).all():  # a file shorter than half a window
        return np.full(len(force), rest_offset(force, contact_n))
    return pd.Series(rest).interpolate(limit_direction="both").to_numpy()


def _window_rest(force: np.ndarray, window: int, contact_n: float) -> np.ndarray:
    """Per row, :func:`rest_offset` of the ``window`` values ending at it (NaN where fewer
    than half of them are finite), a block of rows at a time: each window sorted, its
    10th percentile interpolated as numpy's, the band around it a run of the sorted
    values, and the run's median."""
    n = len(force)
    padded = np.r_[np.full(window - 1, np.inf), np.where(np.isfinite(force), force, np.inf)]
    out = np.full(n, np.nan)
    block = max(1, 2_000_000 // window)
    for start in range(0, n, block):
        ordered = np.sort(np.lib.stride_tricks.sliding_window_view(
            padded[start:start + block + window - 1], window), axis=1)
        rows = np.arange(len(ordered))
        count = np.isfinite(ordered).sum(axis=1)  # the unusable rows sort last, as inf
        position = 0.1 * np.maximum(count - 1, 0)
        below, frac = np.floor(position).astype(int), position % 1
        with np.errstate(invalid="ignore"):  # inf - inf: windows too empty to count
            step = ordered[rows, np.minimum(below + 1, window - 1)] - ordered[rows, below]
            low = ordered[rows, below] + np.where(frac > 0, frac * step, 0.0)
        first = (ordered < (low - contact_n / 2)[:, None]).sum(axis=1)
        size = (ordered <= (low + contact_n / 2)[:, None]).sum(axis=1) - first
        middle = (ordered[rows, first + (size - 1) // 2]
                  + ordered[rows, first + size // 2]) / 2
        out[start:start + len(ordered)] = np.where(count >= max(1, window // 2), middle,
                                                   np.nan)
    return out


def rest_offset(force: np.ndarray, contact_n: float) -> float:
    """What a file's force sensor reads at rest: the median of the rows within half the
    contact threshold of the file's 10th percentile. Presses only push the force up, so
    the low tail is rest as long as a tenth of the file is; the band around it keeps out
    the presses, and the median of rest rows is unbiased for symmetric noise."""
    finite = force[np.isfinite(force)]
    if not len(finite):
        return float("nan")
    low = np.percentile(finite, 10)
    return float(np.median(finite[np.abs(finite - low) <= contact_n / 2]))


def on_grid(mm: np.ndarray, lines: tuple[float, ...], tolerance: float
            ) -> tuple[np.ndarray, np.ndarray]:
    """Each position (mm) as the index (1-based) of the nearest grid line, and whether it
    lies within ``tolerance`` of it."""
    coords = np.asarray(lines, dtype=float)
    nearest = np.abs(mm[:, None] - coords[None, :]).argmin(axis=1)
    return nearest + 1, np.abs(mm - coords[nearest]) <= tolerance


def tolerance_mm(spec: Import, skin: AnySkin) -> float:
    """How far a position may lie from its grid line: as set, else a quarter of the
    skin's finest pitch (1 mm on a grid of one line)."""
    if spec.position_tolerance_mm is not None:
        return float(spec.position_tolerance_mm)
    pitches = [np.diff(coords).min() for coords in (skin.x_mm, skin.y_mm)
               if coords is not None and len(coords) > 1]
    return float(min(pitches)) / 4 if pitches else 1.0


@dataclass(frozen=True)
class _Map:
    """Where each value of one file is: header positions by role."""

    header: list[str]
    channels: list[int]           # in the skin's channel order
    columns: dict[str, int]       # import.columns key (force, x_mm, time, …) → position
    named: dict[str, float]       # position key → value from the file's name


def _column_map(path: Path, spec: Import, kind: str, skin: AnySkin) -> tuple[_Layout, _Map]:
    """``path``'s layout, the positions of the columns ``import.columns`` names in its
    header, and the positions its name gives: a DatasetError naming the file and the key
    otherwise."""
    layout = _file_layout(path, kind, skin)
    if layout.header is None:
        raise DatasetError(f"{path}:1: no header row; import.columns names the columns by "
                           "the header's names")
    header = [str(name).strip() for name in layout.header]
    where = {name: i for i, name in reversed(list(enumerate(header)))}

    def find(name: str, key: str) -> int:
        if name in where:
            return where[name]
        lower = {h.lower(): h for h in reversed(header)}  # case is the commonest slip
        close = difflib.get_close_matches(name.lower(), list(lower), n=1)
        hint = f"; did you mean {lower[close[0]]!r}?" if close else ""
        raise DatasetError(f"{path}:1: no column {name!r} (import.columns.{key}){hint} "
                           f"(the header: {', '.join(header[:30])})")

    wanted = spec.columns.channels
    if wanted is None:
        channels = [find(name, "channels, by default the skin's channel names")
                    for name in skin.channels]
    elif isinstance(wanted, list):
        channels = [find(name, "channels") for name in wanted]
    else:
        channels = [i for i, name in enumerate(header) if fnmatch.fnmatchcase(name, wanted)]
        if len(channels) != skin.terminals:
            raise DatasetError(
                f"{path}:1: import.columns.channels = {wanted!r} matches {len(channels)} "
                f"column(s) ({', '.join(header[i] for i in channels[:20]) or 'none'}), but "
                f"the skin has {skin.terminals} channels ({skin.describe()})")
    columns = {key: find(name, key) for key, name in
               spec.columns.model_dump(exclude_none=True).items() if key != "channels"}
    named: dict[str, float] = {}
    if spec.position_from_name is not None:
        match = re.search(spec.position_from_name, path.name)
        if match is None:
            raise DatasetError(f"{path}: the file's name does not match "
                               f"import.position_from_name {spec.position_from_name!r}")
        for key, text in match.groupdict().items():
            try:
                named[key] = float(text)
            except (TypeError, ValueError):
                raise DatasetError(f"{path}: position_from_name gives {key} = {text!r}, not "
                                   "a number") from None
            if key.endswith("_mm"):
                _, near = on_grid(np.array([named[key]]), getattr(skin, f"{key[0]}_mm"),
                                  tolerance_mm(spec, skin))
                if not near[0]:
                    raise DatasetError(
                        f"{path}: its name places {key[:-3]} at {named[key]:g} mm, off the "
                        f"skin's grid (skin.{key[0]}_mm: "
                        f"{', '.join(f'{v:g}' for v in getattr(skin, f'{key[0]}_mm'))}; "
                        f"tolerance {tolerance_mm(spec, skin):g} mm)")
    layout.width = len(header)
    return layout, _Map(header, channels, columns, named)


def _read_cells(path: Path, layout: _Layout) -> tuple[pd.DataFrame, np.ndarray, np.ndarray]:
    """A whole file's cells (text for CSV), line numbers and row-length reasons."""
    parts = list(_raw_chunks(path, layout))
    if not parts:
        raise DatasetError(f"{path}: no data rows")
    return (pd.concat([cells for cells, _, _ in parts], ignore_index=True),
            np.concatenate([lines for _, lines, _ in parts]),
            np.concatenate([reasons for _, _, reasons in parts]))


def _judge_file(path: Path, spec: Import, kind: str, skin: AnySkin) -> _Judged:
    """Read one file through the column map and make its rows' labels (see above)."""
    layout, mapped = _column_map(path, spec, kind, skin)
    cells, lines, reasons = _read_cells(path, layout)
    names = {**{c: mapped.channels[j] for j, c in enumerate(skin.channels)},
             **{k: i for k, i in mapped.columns.items() if k != "trial"}}
    raw = cells[list(names.values())].set_axis(list(names), axis=1)
    numeric = raw.apply(pd.to_numeric, errors="coerce").astype(float)
    missing = numeric.isna().to_numpy()
    text_cell = np.zeros_like(missing)
    if missing.any():
        rows, cols = np.nonzero(missing)
        text_cell[rows, cols] = ~_blank(raw.to_numpy(dtype=object)[rows, cols]).astype(bool)
    shown = {key: f"{mapped.header[i]} ({key})" if key in mapped.columns
             else mapped.header[i] for key, i in names.items()}
    text = first_reason([(text_cell[:, j], f"{shown[key]} is not a number")
                         for j, key in enumerate(names)], raw.index).to_numpy()
    reasons = np.where(reasons == "", text, reasons)
    channels = numeric[skin.channels].to_numpy()
    hiccups, _ = _hiccups(channels, np.full((1, skin.terminals), np.nan))
    reasons = np.where(hiccups != "", hiccups, reasons).astype(object)

    if "rest" in mapped.columns:
        reasons = np.where((reasons == "") & ~np.isfinite(numeric["rest"].to_numpy()),
                           f"{mapped.header[mapped.columns['rest']]} (rest) is NaN or empty",
                           reasons)
    labels, at_rest, offset, rule = _labels_of(numeric, mapped, spec, kind, skin, reasons,
                                               path)
    reasons = np.where(reasons == "", rule, reasons)
    checks = labels.assign(**{c: numeric[c] for c in skin.channels})
    more = np.where(at_rest, "", row_problems(checks, import_kind(kind, spec).name,
                                               skin).to_numpy())
    reasons = np.where(reasons == "", more, reasons)
    if "time" in numeric:
        t_ms = numeric["time"].to_numpy() * 1000.0
        reasons = np.where((reasons == "") & ~np.isfinite(t_ms), "time is NaN or empty",
                           reasons)
    else:
        t_ms = np.full(len(numeric), np.nan)
    trial = _file_trials(cells, mapped, spec, t_ms)
    if "trial" in mapped.columns:
        empty = _blank(cells[mapped.columns["trial"]].to_numpy(dtype=object)).astype(bool)
        reasons = np.where((reasons == "") & empty,
                           f"{mapped.header[mapped.columns['trial']]} (trial) is empty", reasons)
    hashes = pd.util.hash_pandas_object(numeric[skin.channels], index=False).to_numpy()
    return _Judged(cells, lines, channels, labels, reasons.astype(object), at_rest, trial,
                   t_ms, offset, hashes)


def _labels_of(numeric: pd.DataFrame, mapped: _Map, spec: Import, kind: str,
               skin: AnySkin, reasons: np.ndarray, path: Path):
    """(label columns, rows at rest, the file's rest offset (:class:`_RestOffset`), per-row
    reasons of the contact rule and the grid) for one file."""
    the_kind = get_kind(kind)
    n = len(numeric)
    scale = FORCE_UNITS[spec.force_unit] * spec.force_sign
    forces = {f: numeric[f].to_numpy() * scale
              for f in dict.fromkeys([*the_kind.force_columns, "force"]) if f in numeric}
    problems = np.full(n, "", dtype=object)
    offset = None
    if spec.contact_n is not None:
        contact_n = float(spec.contact_n)
        usable = reasons == ""
        total = sum(forces.values())
        rest = rest_force(np.where(usable, total, np.nan), spec, numeric, path)
        offset = _RestOffset.of(rest[usable], spec)
        share = {f: np.divide(values, total, out=np.zeros(n), where=total != 0)
                 for f, values in forces.items()} if len(forces) > 1 else dict.fromkeys(forces, 1.0)
        residual = total - rest
        rule = spec.rest or Rest()
        tolerance = contact_n if rule.below_n is None else float(rule.below_n)
        below = residual < -tolerance
        problems[below] = [f"force is {-r:.3g} N below the file's rest ({at:.3g} N) by more "
                           f"than {tolerance:g} N (import.rest.below_n, default contact_n): is "
                           "import.force_sign right?"
                           for r, at in zip(residual[below], rest[below], strict=True)]
        pressed = residual > contact_n
        # Per-contact forces keep their shares of the total once the offset is removed.
        forces = {f: np.where(pressed, residual * share[f], 0.0) for f in forces}
    else:
        pressed = np.ones(n, dtype=bool)
    at_rest = ~pressed if the_kind.several else np.zeros(n, dtype=bool)
    out: dict[str, np.ndarray] = {}
    tolerance = tolerance_mm(spec, skin) if any(k.endswith("_mm") for k in
                                                spec.position_sources()) else 0.0
    for node in the_kind.node_columns:
        axis = node[0]
        key = node if (node in mapped.columns or node in mapped.named) else f"{node}_mm"
        values = (numeric[key].to_numpy() if key in mapped.columns
                  else np.full(n, mapped.named[key]))
        if key.endswith("_mm"):
            index, near = on_grid(np.nan_to_num(values, nan=np.inf), getattr(skin, f"{axis}_mm"),
                                  tolerance)
            off = pressed & np.isfinite(values) & ~near & (problems == "")
            problems[off] = [f"{key} = {v:g} is off the skin's grid (skin.{axis}_mm; "
                             f"tolerance {tolerance:g} mm)" for v in values[off]]
            values = np.where(np.isfinite(values), index, np.nan)
        out[node] = np.where(pressed, values, 0.0)
    for force in forces:
        out[force] = forces[force]
    out = the_kind.in_label_order(out, skin)
    out["stretch"] = numeric["stretch"].to_numpy() if "stretch" in numeric else np.ones(n)
    labels = pd.DataFrame({c: out[c] for c in import_kind(kind, spec).labels})
    return labels, at_rest, offset, problems


def _file_trials(cells: pd.DataFrame, mapped: _Map, spec: Import, t_ms: np.ndarray
                 ) -> np.ndarray | None:
    """Each row's trial within its file: the trial column's value, the file (0) or a
    block of trial_s seconds; None for runs of identical labels (counted over the rows
    kept: :func:`_local_trials`)."""
    if "trial" in mapped.columns:
        return cells[mapped.columns["trial"]].astype(str).str.strip().to_numpy(dtype=object)
    if spec.trials == "file":
        return np.zeros(len(cells), dtype=np.int64)
    if spec.trials == "time":
        start = np.nanmin(t_ms) if np.isfinite(t_ms).any() else 0.0
        since = np.nan_to_num(t_ms - start)  # a row without a time is set aside anyway
        return np.floor(since / (float(spec.trial_s) * 1000.0)).astype(np.int64)
    return None  # runs of labels: counted over the rows kept


def import_recording(files: list[Path], spec: Import, kind: str, skin: AnySkin, out: Path, *,
                     bad_rows: str = "error", scene: str | None = None
                     ) -> tuple[list[dict], dict]:
    """Read ``files`` (another instrument's, through ``spec``'s column map) into the
    dataset file ``out``: (quarantined rows, metadata). Two passes, one file at a time: the
    first judges every row, finds copies of earlier rows across files and counts; the
    second writes, the counts in the footer from the start."""
    check_policy(bad_rows)
    files = [Path(f) for f in files]
    digests = [sha256_file(f) for f in files]
    digest = hashlib.sha256("".join(digests).encode()).hexdigest()
    by_trial_column = spec.columns.trial is not None
    # Pass 1: reasons, copies of earlier rows, counts, and the trials the labels make.
    hashes, where, touching, trial_rows, per_file = [], [], [], [], []
    counts = dict.fromkeys(("rows_in_file", "rows_quarantined", "dropped_frames",
                            "stale_repeats", "rows_at_rest"), 0)
    bad_count, first_bad = 0, None
    for number, path in enumerate(files):
        judged = _judge_file(path, spec, kind, skin)
        bad = judged.reasons != ""
        serious = bad & ~np.isin(judged.reasons, [DROPPED, STALE])
        bad_count += int(serious.sum())
        if first_bad is None and serious.any():
            i = int(np.argmax(serious))
            first_bad = f"{path}:{judged.lines[i]}: {judged.reasons[i]}"
        kept = ~bad & ~judged.at_rest
        counts["rows_in_file"] += len(bad)
        counts["rows_quarantined"] += int(bad.sum())
        counts["dropped_frames"] += int((judged.reasons == DROPPED).sum())
        counts["stale_repeats"] += int((judged.reasons == STALE).sum())
        counts["rows_at_rest"] += int((~bad & judged.at_rest).sum())
        hashes.append(judged.hashes[kept])
        where.append(np.column_stack([np.full(kept.sum(), number), judged.lines[kept]]))
        touching.append(_touching(judged.labels[kept], kind))
        trial_rows += _trial_sizes(judged, kept)
        per_file.append({"name": path.name, "sha256": digests[number], "rows": len(bad),
                         "rows_kept": int(kept.sum()),
                         **(judged.rest_offset.entry() if judged.rest_offset is not None
                            else {"rest_offset_n": None})})
    copies = _copies_across(hashes, where)
    if copies:
        bad_count += len(copies)
        (number, line), (first_number, first_line) = min(copies.items())
        if first_bad is None:
            first_bad = (f"{files[number]}:{line}: duplicate of {files[first_number].name}:"
                         f"{first_line} (every channel equal)")
    if bad_count and bad_rows == "error":
        raise DatasetError(f"{first_bad} ({bad_count} bad row(s) in all). Set "
                           "ingest.bad_rows: quarantine to set them aside.")
    ones = sum(1 for size in trial_rows if size == 1)
    if spec.trials == "labels" and not by_trial_column and len(trial_rows) >= 10 \
            and ones > len(trial_rows) / 2:
        raise DatasetError(
            f"{spec.path}: {ones:,} of {len(trial_rows):,} trials are one row long (a trial "
            "is a run of rows with the same labels, and these change from row to row): set "
            "scenes.<scene>.import.trials: file, or time with trial_s, or "
            "import.columns.trial")
    copied = np.isin(np.concatenate(where)[:, 0] * (1 << 40) + np.concatenate(where)[:, 1],
                     [f * (1 << 40) + line for f, line in copies])
    contacts = np.concatenate(touching)[~copied]
    if not len(contacts):
        raise DatasetError(f"{spec.path}: no usable rows ({counts['rows_in_file']} data "
                           "row(s), all set aside; see the quarantine file)")
    for number, _ in copies:
        per_file[number]["rows_kept"] -= 1
    counts["rows_quarantined"] += len(copies)
    metadata = _recording_metadata(scene, kind, spec, skin, files[0].parent, digest)
    metadata["source"].update(files=per_file, contact_share=float(contacts.mean()), **counts)
    # Pass 2: write.
    labelled = import_kind(kind, spec)
    labels = labelled.labels
    schema = with_metadata(arrow_schema(labelled.name, skin), metadata)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = out.with_suffix(out.suffix + ".partial")
    quarantine: list[dict] = []
    trial_names: dict = {}
    samples: dict = {}
    with pq.ParquetWriter(partial, schema) as writer:
        for number, path in enumerate(files):
            # Each file is a session of its own: a row's session and seq say which file
            # and which data row of it (metadata source.files names each file's digest).
            session = f"import-{digests[number][:10]}"
            judged = _judge_file(path, spec, kind, skin)
            for i in np.flatnonzero(judged.reasons == ""):
                if (number, int(judged.lines[i])) in copies:
                    f, line = copies[(number, int(judged.lines[i]))]
                    judged.reasons[i] = (f"duplicate of {files[f].name}:{line} (every "
                                         "channel equal)")
            bad = judged.reasons != ""
            for i in np.flatnonzero(bad):
                quarantine.append({"source": str(path), "line": int(judged.lines[i]),
                                   "reason": judged.reasons[i], "text": judged.text(i)})
            kept = ~bad & ~judged.at_rest
            frame = pd.DataFrame(judged.channels[kept], columns=skin.channels)
            for column in labels:
                values = judged.labels[column].to_numpy()[kept]
                frame[column] = (values.astype(np.int64) if column in node_columns(kind)
                                 else values)
            names, sample = [], []
            for value in _local_trials(judged, kept):
                key = value if by_trial_column else (number, value)
                if key not in trial_names:  # a trial column's trials span files
                    trial_names[key] = (f"import-{digest[:10]}-{value}" if by_trial_column
                                        else f"{session}-t{value:05d}")
                names.append(trial_names[key])
                sample.append(samples.get(key, 0))
                samples[key] = sample[-1] + 1
            frame["session"] = session
            frame["trial"] = names
            frame["sample"] = np.array(sample, dtype=np.int64)
            frame["seq"] = np.flatnonzero(kept).astype(np.int64)
            t_ms = judged.t_ms[kept]
            frame["t_ms"] = pd.array(np.where(np.isfinite(t_ms), np.round(t_ms), np.nan),
                                     dtype="Int64")
            if len(frame):
                writer.write_table(pa.Table.from_pandas(frame[[*skin.channels, *labels,
                                                               *PROVENANCE]],
                                                        schema=schema, preserve_index=False))
    os.replace(partial, out)
    return quarantine, metadata


def _touching(labels: pd.DataFrame, kind: str) -> np.ndarray:
    """Whether each row is a contact: force > 0 at a node; every row of several contacts
    (their scenes keep pressed rows only)."""
    if get_kind(kind).several:
        return np.ones(len(labels), dtype=bool)
    return contact_mask(labels)


def _local_trials(judged: _Judged, kept: np.ndarray) -> list:
    """Each kept row's trial within its file: as judged, or a run of identical labels."""
    if judged.trial is not None:
        return list(judged.trial[kept])
    values = judged.labels.to_numpy(dtype=float)[kept]
    if not len(values):
        return []
    starts = np.r_[True, (values[1:] != values[:-1]).any(axis=1)]
    return list(np.cumsum(starts) - 1)


def _trial_sizes(judged: _Judged, kept: np.ndarray) -> list[int]:
    return pd.Series(_local_trials(judged, kept), dtype=object).value_counts().tolist()


def _copies_across(hashes: list[np.ndarray], where: list[np.ndarray]
                   ) -> dict[tuple[int, int], tuple[int, int]]:
    """{(file, line) of a copy: (file, line) of the row it repeats}, across files."""
    if not hashes:
        return {}
    places = np.concatenate(where) if where else np.empty((0, 2), np.int64)
    order_key = places[:, 0] * (1 << 40) + places[:, 1]  # file, then line
    found = _copies(np.concatenate(hashes), order_key)
    return {(k >> 40, k & ((1 << 40) - 1)): (v >> 40, v & ((1 << 40) - 1))
            for k, v in found.items()}


def _recording_metadata(scene: str | None, kind: str, spec: Import, skin: AnySkin,
                        folder: Path, digest: str) -> dict:
    columns = spec.columns
    return {"scene": scene or kind, "kind": kind, "plan": None, "device": None,
            "simulator": None,
            "source": {"kind": "import", "path": str(folder), "sha256": digest,
                       "imported_from": spec.path, "stretch_assumed": columns.stretch is None,
                       "force": {"unit": spec.force_unit, "sign": spec.force_sign,
                                 "contact_n": spec.contact_n,
                                 # the rest rule, where one is set (low_tail: none)
                                 **({"rest": spec.rest.model_dump(exclude_none=True)}
                                    if spec.rest is not None else {})},
                       "trials": ("column" if columns.trial is not None else spec.trials),
                       "trial_s": spec.trial_s},
            **labels_metadata(import_kind(kind, spec)), **skin_metadata(skin)}
