"""Import memory benchmark (``make bench``): peak memory of importing a large CSV.

For each size it writes a valid single-force CSV in the paper's layout, then
imports it (``import_to_dataset``, the ingest step's code) in a fresh process
and reads that process's peak resident memory. The baseline is a second fresh
process that imports the same modules and reads nothing, run by the same
code: the import's own memory is the difference, stated as a ratio to the
file's size.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv

from eskin.data.schema import LABELS
from eskin.kinds import ONE_CONTACT
from eskin.skin import PAPER_SKIN


def write_paper_csv(path: Path, rows: int, seed: int = 0, block: int = 500_000) -> int:
    """A valid single-force CSV of ``rows`` rows (trials of 20 samples) in the paper's
    layout (its skin's channels, then the labels: what the importer reads); its size."""
    rng = np.random.default_rng(seed)
    channels = PAPER_SKIN.channels
    names = channels + LABELS[ONE_CONTACT.name]
    with pacsv.CSVWriter(path, pa.schema([(n, pa.float64()) for n in names])) as writer:
        for start in range(0, rows, block):
            n = min(block, rows - start)
            trial = (start + np.arange(n)) // 20
            data = {c: np.round(rng.normal(500, 40, n), 3) for c in channels}
            data["force"] = np.where(trial % 5 == 0, 0.0, 1.2936 + trial % 4)
            data["x"] = (trial % 11).astype(float)
            data["y"] = ((trial // 11) % 11).astype(float)
            data["stretch"] = 1.0 + (trial % 3) * 0.07921
            writer.write_table(pa.table({n: data[n] for n in names}))
    return path.stat().st_size


_CHILD = """
import json, resource, sys, time
from pathlib import Path
from eskin.data.importer import import_to_dataset
from eskin.kinds import ONE_CONTACT
started = time.perf_counter()
if sys.argv[1] != "-":
    import_to_dataset(Path(sys.argv[1]), ONE_CONTACT.name, Path(sys.argv[2]), bad_rows="error")
print(json.dumps({"seconds": time.perf_counter() - started,
                  "peak_kib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}))
"""


def _child(*args: str) -> dict:
    done = subprocess.run([sys.executable, "-c", _CHILD, *args], capture_output=True,
                          text=True, check=True, timeout=7200)
    return json.loads(done.stdout.strip().splitlines()[-1])


def import_memory(sizes: list[int], scratch: Path | None = None) -> list[dict]:
    """Peak memory of importing each size, against the baseline process."""
    results = []
    with tempfile.TemporaryDirectory(prefix="eskin-memory-", dir=scratch) as folder:
        folder = Path(folder)
        baseline = _child("-")
        for rows in sizes:
            source = folder / f"paper_{rows}.csv"
            size = write_paper_csv(source, rows)
            started = time.perf_counter()
            run = _child(str(source), str(folder / "out.parquet"))
            extra = (run["peak_kib"] - baseline["peak_kib"]) * 1024
            results.append({
                "rows": rows, "file_mb": round(size / 1e6, 1),
                "peak_mb": round(run["peak_kib"] * 1024 / 1e6, 1),
                "baseline_mb": round(baseline["peak_kib"] * 1024 / 1e6, 1),
                "import_mb": round(extra / 1e6, 1),
                "ratio_to_file": round(extra / size, 3),
                "seconds": round(time.perf_counter() - started, 1)})
            source.unlink()
    return results


def markdown(results: list[dict]) -> str:
    lines = ["| rows | file (MB) | peak (MB) | baseline process (MB) | import's own (MB) | "
             "ratio to file | time (s) |", "|---:|---:|---:|---:|---:|---:|---:|"]
    lines += [f"| {r['rows']:,} | {r['file_mb']} | {r['peak_mb']} | {r['baseline_mb']} | "
              f"{r['import_mb']} | {r['ratio_to_file']} | {r['seconds']} |" for r in results]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":  # python -m harness.memory_bench 100000
    print(markdown(import_memory([int(a) for a in sys.argv[1:]] or [100_000])))
