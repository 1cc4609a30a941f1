"""Compare variants and audit dataset versions, from the MLflow store and DVC's cache.

A *variant* is one pipeline run (one ``dvc repro`` at a commit and params,
or one ``dvc exp run``; see :mod:`eskin.tracking.runs`): its task runs are its
children, and it carries the whole params file. ``variant_table`` puts the
latest run of every task of every variant side by side; ``dataset_versions``
groups task runs by the DVC md5 of the dataset that trained them.

The tables are pure functions of ``mlflow.search_runs`` frames; reading the
store, git and the workspace happens in the ``load_*`` and ``check_*`` helpers.
"""

from __future__ import annotations

import ast
import io
import subprocess
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from eskin.catalog import HEADLINE_METRIC, SCORED_TASKS, model_path, processed_path
from eskin.data.schema import md5_file
from eskin.errors import EskinError

TASK_KINDS = ("task", "scores")
# The score that stands for a target in a table, by what the target is.
HEADLINE_SCORES = tuple(dict.fromkeys(HEADLINE_METRIC.values()))
TASK_ORDER = {t: i for i, t in enumerate(SCORED_TASKS)}


class NoRunsError(EskinError, LookupError):
    """The tracking store holds nothing to compare or audit."""


def _tag(runs: pd.DataFrame, name: str) -> pd.Series:
    column = f"tags.{name}"
    return runs[column] if column in runs else pd.Series("", index=runs.index, dtype=object)


def _seconds(runs: pd.DataFrame) -> pd.Series:
    return (runs["end_time"] - runs["start_time"]).dt.total_seconds()


def split_runs(runs: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(pipeline runs, task and scoring runs) of an ``mlflow.search_runs`` frame."""
    if runs.empty:
        from eskin.tracking.connection import log_pipeline_command

        raise NoRunsError("no runs in the tracking store: run "
                          f"{log_pipeline_command()} (or `dvc exp run`)")
    kind = _tag(runs, "eskin.kind")
    return runs[kind == "pipeline"], runs[kind.isin(TASK_KINDS)]


def latest_per_task(children: pd.DataFrame) -> pd.DataFrame:
    """The newest run of each (pipeline, scene, task)."""
    keyed = children.assign(_parent=_tag(children, "mlflow.parentRunId"),
                            _scene=_tag(children, "eskin.scene"),
                            _task=_tag(children, "eskin.task"))
    keyed = keyed.sort_values("start_time")
    return keyed.drop_duplicates(["_parent", "_scene", "_task"], keep="last")


def headline_columns(children: pd.DataFrame, scheme: str) -> list[str]:
    """``metrics.<scheme>.<target>.<r2|accuracy>`` columns, and scoring runs' pair accuracy."""
    prefix = f"metrics.{scheme}."
    found = []
    for column in children.columns:
        if not column.startswith(prefix) or children[column].isna().all():
            continue
        parts = column[len(prefix):].split(".")
        if (len(parts) == 2 and parts[1] in HEADLINE_SCORES) or parts == ["pair_accuracy"]:
            found.append(column)
    return found


def _metric_label(column: str, scheme: str) -> str:
    name = column.removeprefix(f"metrics.{scheme}.")
    if name == "pair_accuracy":
        return "pairs acc"
    target, score = name.split(".")
    return f"{target} {'R²' if score == 'r2' else 'acc'}"


def _metric_order(children: pd.DataFrame, column: str) -> tuple[str, int, str, str]:
    has = children[children[column].notna()]
    scene = _tag(has, "eskin.scene").iloc[0] if len(has) else ""
    task = _tag(has, "eskin.task").iloc[0] if len(has) else ""
    target = column.split(".")[-2]
    contact = target[-1] if target[-1].isdigit() else ""  # x1, y1, then x2, y2
    return scene, TASK_ORDER.get(task, 9), contact, column


def run_seconds(runs: pd.DataFrame) -> pd.Series:
    """A task run's wall time: the training step's own clock (``wall_seconds``: data
    loading, cross-validation, refit, logging), else the MLflow run's duration."""
    duration = _seconds(runs)
    if "metrics.wall_seconds" in runs:
        return runs["metrics.wall_seconds"].fillna(duration)
    return duration


def differing_params(pipelines: pd.DataFrame) -> list[str]:
    """``params.*`` columns holding more than one value across the pipeline runs.

    A param one run records and another does not is a difference too, shown as — where
    absent: a model switched for every kind of scene (``train.force.model``) against one
    given per kind (``train.force.model.single_force``) is a key in one run's params only.
    """
    def differs(values: pd.Series) -> bool:
        recorded = values.dropna()  # search_runs leaves a param a run lacks as None or NaN
        return recorded.nunique() > 1 or 0 < len(recorded) < len(values)

    return sorted(c for c in pipelines.columns if c.startswith("params.") and differs(pipelines[c]))


def variant_table(runs: pd.DataFrame, scheme: str = "conditions", *,
                  variants: list[str] | None = None, last: int | None = None) -> pd.DataFrame:
    """One row per variant: its name, commit, datasets, the params that differ from
    the other variants shown, each task's headline score under ``scheme``, and the
    summed run time of its task runs. Variants of the same name keep their newest
    run; ``variants`` picks some by name, ``last`` keeps the newest few."""
    pipelines, children = split_runs(runs)
    if children.empty:
        raise NoRunsError("the tracking store holds pipeline runs but no task runs")
    latest = latest_per_task(children)
    pipelines = pipelines[pipelines["run_id"].isin(set(latest["_parent"]))]
    pipelines = (pipelines.assign(_name=_tag(pipelines, "mlflow.runName"))
                 .sort_values("start_time").drop_duplicates("_name", keep="last"))
    if variants:
        unknown = sorted(set(variants) - set(pipelines["_name"]))
        if unknown:
            raise NoRunsError(f"no variant named {', '.join(unknown)}; known: "
                              f"{', '.join(pipelines['_name'])}")
        pipelines = pipelines[pipelines["_name"].isin(variants)]
    if last:
        pipelines = pipelines.tail(last)
    latest = latest[latest["_parent"].isin(set(pipelines["run_id"]))]
    # (scene, metric) pairs: two scenes of a kind log the same metric names. A label is
    # prefixed with its scene only where another scene has the same label.
    scored = sorted({(scene, column) for column in headline_columns(latest, scheme)
                     for scene in latest.loc[latest[column].notna(), "_scene"].unique()},
                    key=lambda sc: (sc[0], _metric_order(latest, sc[1])[1:]))
    labels = [_metric_label(column, scheme) for _, column in scored]
    shared = {label for label in labels if labels.count(label) > 1}
    labels = [f"{scene}: {label}" if label in shared else label
              for (scene, _), label in zip(scored, labels, strict=True)]
    param_columns = differing_params(pipelines)
    rows = []
    for _, pipeline in pipelines.iterrows():
        own = latest[latest["_parent"] == pipeline["run_id"]]
        row: dict[str, Any] = {
            "variant": pipeline["_name"],
            "commit": str(pipeline.get("tags.eskin.git_commit") or "")[:8],
            "datasets": " ".join(sorted({f"{s}:{d[:8]}" for s, d in zip(
                own["_scene"], _tag(own, "eskin.dataset_digest"), strict=True) if d})),
        }
        for column in param_columns:
            row[column.removeprefix("params.")] = pipeline[column]
        for (scene, column), label in zip(scored, labels, strict=True):
            values = own.loc[own["_scene"] == scene, column].dropna()
            row[label] = values.iloc[-1] if len(values) else np.nan
        # runs that trained: a task DVC reused has a run too, but its time is another's
        trained = own[_tag(own, "eskin.trained") != "reused"]
        row["runs"] = len(trained)
        row["run time s"] = round(float(run_seconds(trained).sum()), 1)
        row["finished"] = own["end_time"].max()
        rows.append(row)
    return pd.DataFrame(rows)


def dataset_versions(runs: pd.DataFrame, workspace: Mapping[str, str] | None = None,
                     committed: Mapping[str, str] | None = None) -> pd.DataFrame:
    """One row per dataset version (DVC md5) that trained a task run: scene, rows,
    source, when it was first committed and first used, its runs and variants, and
    whether the workspace holds it (``workspace``: scene → md5 of the workspace file)."""
    pipelines, children = split_runs(runs)
    workspace, committed = workspace or {}, committed or {}
    children = children[_tag(children, "eskin.dataset_digest").fillna("") != ""]
    if children.empty:
        raise NoRunsError("no task run in the tracking store names its dataset")
    names = dict(zip(pipelines["run_id"], _tag(pipelines, "mlflow.runName"), strict=True))
    keyed = children.assign(_digest=_tag(children, "eskin.dataset_digest"),
                            _scene=_tag(children, "eskin.scene"))
    rows = []
    for (scene, digest), group in keyed.groupby(["_scene", "_digest"], sort=False):
        variants = sorted({names.get(p, "?") for p in _tag(group, "mlflow.parentRunId")})
        rows.append({
            "dataset md5": digest, "scene": scene,
            "rows": _first(_tag(group, "eskin.dataset_rows")),
            "source": _first(_tag(group, "eskin.dataset_source")),
            "committed": committed.get(digest, ""),
            "first used": group["start_time"].min(),
            "runs": len(group), "variants": ", ".join(variants),
            "workspace": "yes" if workspace.get(scene) == digest else "",
        })
    table = pd.DataFrame(rows)
    return table.sort_values(["scene", "first used"]).reset_index(drop=True)


def runs_of_dataset(runs: pd.DataFrame, digest: str) -> pd.DataFrame:
    """The task runs a dataset version trained: id, scene/task, model, variant, commit."""
    pipelines, children = split_runs(runs)
    names = dict(zip(pipelines["run_id"], _tag(pipelines, "mlflow.runName"), strict=True))
    used = children[_tag(children, "eskin.dataset_digest") == digest].sort_values("start_time")
    return pd.DataFrame({
        "run": used["run_id"],
        "task": _tag(used, "eskin.scene") + "/" + _tag(used, "eskin.task"),
        "model": _tag(used, "eskin.model").fillna(""),
        "variant": [names.get(p, "?") for p in _tag(used, "mlflow.parentRunId")],
        "commit": _tag(used, "eskin.git_commit").str[:8],
        "started": used["start_time"],
    }).reset_index(drop=True)


def _first(values: pd.Series) -> str:
    values = values.dropna()
    values = values[values != ""]
    return str(values.iloc[0]) if len(values) else ""


# A table's times, to the minute: a reader places a run by them, and the seconds would
# take three more columns of a terminal (markdown and csv keep them).
TABLE_TIME = "%Y-%m-%d %H:%M"
FULL_TIME = "%Y-%m-%d %H:%M:%S"
MISSING = "—"
SIGNIFICANT = 4  # digits of a column's largest number


def render(table: pd.DataFrame, fmt: str) -> str:
    """A table as ``table`` (aligned text), ``markdown`` or ``csv``. In text and markdown,
    each column of numbers has one format: as many decimals as give its largest value
    :data:`SIGNIFICANT` digits (0.9400 beside 0.8585, not 0.94), missing as —."""
    if fmt not in ("table", "markdown", "csv"):
        raise ValueError(f"format must be table, markdown or csv, got {fmt!r}")
    table = table.copy()
    for column in table.columns:
        if pd.api.types.is_datetime64_any_dtype(table[column]):
            table[column] = table[column].dt.strftime(TABLE_TIME if fmt == "table"
                                                      else FULL_TIME)
    if fmt == "csv":
        return table.to_csv(index=False)
    header = [str(c) for c in table.columns]
    numeric = [pd.api.types.is_numeric_dtype(table[c]) for c in table.columns]
    columns = [_column_cells(table[c]) for c in table.columns]
    rows = [list(row) for row in zip(*columns, strict=True)] if len(table) else []
    if fmt == "markdown":
        from tabulate import tabulate

        # numparse off: tabulate would read the cells as numbers and format them again
        return tabulate(rows, header, tablefmt="pipe", disable_numparse=True,
                        colalign=["right" if n else "left" for n in numeric]) + "\n"
    return _rich_table(header, rows, numeric)


def _column_cells(values: pd.Series) -> list[str]:
    """A column's cells as text, numbers in the column's one format."""
    if pd.api.types.is_bool_dtype(values) or not pd.api.types.is_numeric_dtype(values):
        return [MISSING if v is None or v is pd.NaT or (isinstance(v, float) and np.isnan(v))
                else str(v) for v in values]
    if pd.api.types.is_integer_dtype(values):
        return [str(v) for v in values]
    largest = float(np.nanmax(np.abs(values))) if values.notna().any() else 0.0
    whole_digits = len(str(int(largest))) if largest >= 1 else 0
    decimals = max(0, SIGNIFICANT - whole_digits)
    return [MISSING if np.isnan(v) else f"{v:.{decimals}f}" for v in values.astype(float)]


def _rich_table(header: list[str], rows: list[list[str]], numeric: list[bool]) -> str:
    """Aligned text no wider than the terminal (``COLUMNS``), no cell ever wrapped: a row
    per item where that fits, else turned on its side (a column per item, a row per
    field), which is how a few variants of many scores read best, cut into as many tables
    as it takes for each to fit. So an identifier a reader copies (``eskin audit --run
    <id>``, a DVC md5) is whole on one line, and a date is never cut in two."""
    import shutil

    width = shutil.get_terminal_size((160, 24)).columns
    widths = [_widest(i, header, rows) for i in range(len(header))]
    if _table_width(widths) <= width or not rows:
        return _print_table(header, rows, numeric, width)
    # on its side: the first column's values head the columns
    fields = [[h, *(r[i] for r in rows)] for i, h in enumerate(header) if i]
    side_header = [header[0], *(r[0] for r in rows)]
    mostly_numbers = 2 * sum(numeric[1:]) > len(numeric) - 1  # scores: right-aligned
    side_numeric = [False, *[mostly_numbers] * len(rows)]
    side_widths = [_widest(i, side_header, fields) for i in range(len(side_header))]
    parts, chunk = [], [0]
    for i in range(1, len(side_header)):
        if len(chunk) > 1 and _table_width([side_widths[j] for j in (*chunk, i)]) > width:
            parts.append(chunk)
            chunk = [0]
        chunk.append(i)
    parts.append(chunk)
    return "\n".join(_print_table([side_header[j] for j in part],
                                  [[f[j] for j in part] for f in fields],
                                  [side_numeric[j] for j in part], width) for part in parts)


def _widest(i: int, header: list[str], rows: list[list[str]]) -> int:
    return max([len(header[i]), *(len(r[i]) for r in rows)])


def _table_width(widths: list[int]) -> int:
    """How wide :func:`_print_table` prints columns this wide: 3 characters between two."""
    return sum(widths) + 3 * (len(widths) - 1)


def _print_table(header: list[str], rows: list[list[str]], numeric: list[bool],
                 width: int) -> str:
    """One rich table, every column as wide as its widest cell and never wrapped (the
    console is widened if one column on its side is wider than the terminal: a line
    then wraps on screen, but no cell is broken in the text)."""
    from rich import box
    from rich.console import Console
    from rich.table import Table

    shown = Table(box=box.SIMPLE_HEAD, show_edge=False, pad_edge=False)
    for name, is_number in zip(header, numeric, strict=True):
        shown.add_column(name, justify="right" if is_number else "left", no_wrap=True)
    for row in rows:
        shown.add_row(*row)
    widths = [_widest(i, header, rows) for i in range(len(header))]
    console = Console(file=io.StringIO(), width=max(width, _table_width(widths)),
                      color_system=None, highlight=False)
    console.print(shown)
    return console.file.getvalue()


def render_versions(runs: pd.DataFrame, versions: pd.DataFrame, fmt: str) -> str:
    """``eskin audit``: the dataset versions and the runs each trained, every run id whole
    in every format. ``csv``: a row per version, its runs' ids in
    ``run ids`` (space-separated); ``table`` and ``markdown``: the versions, then each
    version's runs under its md5."""
    if fmt == "csv":
        ids = {digest: " ".join(runs_of_dataset(runs, digest)["run"])
               for digest in versions["dataset md5"]}
        return render(versions.assign(**{"run ids": versions["dataset md5"].map(ids)}),
                      "csv")
    parts = [render(versions, fmt)]
    for digest in versions["dataset md5"]:
        trained = render(runs_of_dataset(runs, digest), fmt)
        parts.append(f"\n{digest} trained:\n\n{trained}" if fmt == "markdown"
                     else f"\n{digest} trained:\n{trained}")
    return "".join(parts)


# --- reading the store, git and the workspace --------------------------------------------

def load_runs(experiment: str | None = None) -> pd.DataFrame:
    """Every run of the project's MLflow experiment (``eskin.tracking.connection.tracking_uri``)."""
    import mlflow

    from eskin.tracking import connection, runs

    client = connection.connect()
    name = experiment or connection.EXPERIMENT
    experiment_ = mlflow.get_experiment_by_name(name)
    if experiment_ is None:
        raise NoRunsError(f"no MLflow experiment {name!r} at {connection.tracking_uri()}: "
                          f"run {connection.log_pipeline_command()} first "
                          "(or set MLFLOW_TRACKING_URI)")
    # A run a killed stage left RUNNING is shown as what it is: FAILED.
    runs.settle_stale_runs(client, [experiment_.experiment_id])
    return mlflow.search_runs(experiment_names=[name], output_format="pandas")


def workspace_digests(root: Path, scenes: list[str]) -> dict[str, str]:
    """scene → md5 of ``data/processed/<scene>.parquet`` in the workspace, where present."""
    out = {}
    for scene in scenes:
        path = Path(root) / processed_path(scene)
        if path.exists():
            out[scene] = md5_file(path)
    return out


def commit_dates(root: Path, digests: list[str]) -> dict[str, str]:
    """md5 → date of the first commit (any branch or DVC experiment) whose dvc.lock names it."""
    out = {}
    for digest in digests:
        try:
            done = subprocess.run(["git", "log", "--all", "--reverse", "--format=%cs %h",
                                   f"-S{digest}", "--", "dvc.lock"], cwd=root, text=True,
                                  capture_output=True, timeout=30, check=True)
        except (OSError, subprocess.SubprocessError):
            continue
        first = done.stdout.splitlines()[:1]
        out[digest] = first[0] if first else "not committed"
    return out


def dvc_cache_path(root: Path, md5: str) -> Path | None:
    """Where DVC's cache keeps the file of this md5, if it is there (hash-checked)."""
    from dvc.repo import Repo

    with Repo(str(root)) as repo:
        path = Path(repo.cache.local.oid_to_path(md5))
    if path.exists() and md5_file(path) == md5:
        return path
    return None


def run_audit(run_id: str, root: Path) -> dict[str, Any]:
    """A run's lineage (dataset version, params, commit, model) and whether the
    workspace and DVC's cache still hold what it used."""
    import mlflow

    from eskin.tracking import connection, runs

    client = connection.connect()
    try:
        run = client.get_run(run_id)
    except mlflow.exceptions.MlflowException as err:
        raise NoRunsError(f"no run {run_id} at {connection.tracking_uri()}") from err
    if runs.settle_stale_runs(client, [run.info.experiment_id]):
        run = client.get_run(run_id)
    tags = run.data.tags
    scene, task = tags.get("eskin.scene", ""), tags.get("eskin.task", "")
    digest = tags.get("eskin.dataset_digest", "")
    root = Path(root)
    checks = {}
    if run.info.status != "FINISHED":
        checks["run finished"] = ("FAILED" if run.info.status != "RUNNING" else "RUNNING",
                                  tags.get("eskin.failure", f"status {run.info.status}: its "
                                           "metrics and models may be incomplete"))
    if digest:
        checks["dataset in workspace"] = _workspace_check(
            root, processed_path(scene), digest, "this version")
        checks["dataset in DVC cache"] = _cache_check(root, digest)
    if tags.get("eskin.model_md5"):
        checks["model in workspace"] = _workspace_check(
            root, model_path(scene, task), tags["eskin.model_md5"],
            "this run's model")
        checks["model in DVC cache"] = _cache_check(root, tags["eskin.model_md5"])
    commit = tags.get("eskin.git_commit", "")
    head = runs.git_commit(root)
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                           capture_output=True, text=True, check=False).stdout.strip()
    checks["commit"] = (("ok", "HEAD" + (", with uncommitted changes" if dirty else ""))
                        if commit and commit == head else ("differs", f"HEAD is {head[:8] or '?'}"))
    registered = [f"{v.name} v{v.version}" for v in
                  client.search_model_versions(f"run_id = '{run_id}'")]
    return {
        "run": run_id, "name": tags.get("mlflow.runName", ""), "scene": scene, "task": task,
        "model": tags.get("eskin.model", ""), "status": run.info.status,
        "commit": commit, "dvc experiment": tags.get("eskin.dvc_experiment", ""),
        "dataset md5": digest, "dataset rows": tags.get("eskin.dataset_rows", ""),
        "dataset source": tags.get("eskin.dataset_source", ""),
        "features md5": tags.get("eskin.features_md5", ""),
        "model md5": tags.get("eskin.model_md5", ""),
        "registered": ", ".join(sorted(registered)),
        "params": dict(sorted(run.data.params.items())),
        "metrics": {k: v for k, v in sorted(run.data.metrics.items())
                    if k.split(".")[-1] in HEADLINE_SCORES + ("pair_accuracy",)},
        "checks": checks,
    }


def _workspace_check(root: Path, path: Path, md5: str, what: str) -> tuple[str, str]:
    """Whether the workspace file ``path`` (relative to ``root``) has this md5."""
    if not (root / path).exists():
        return "differs", f"{path} is missing"
    now = md5_file(root / path)
    return ("ok", f"{path} is {what}") if now == md5 else ("differs", f"{path} is {now}")


def _cache_check(root: Path, md5: str) -> tuple[str, str]:
    cached = dvc_cache_path(root, md5)
    if cached is None:
        return "missing", "not in this DVC cache"
    return "ok", str(cached.relative_to(root) if cached.is_relative_to(root) else cached)


def render_audit(report: Mapping[str, Any]) -> str:
    lines = [f"run {report['run']} ({report['name']})"]
    for key in ("scene", "task", "model", "status", "commit", "dvc experiment", "dataset md5",
                "dataset rows", "dataset source", "features md5", "model md5", "registered"):
        lines.append(f"  {key:<15} {report[key] or '—'}")
    lines.append("  params")
    lines += [f"    {k} = {v}" for k, v in report["params"].items()]
    lines.append("  metrics")
    lines += [f"    {k} = {v:.4g}" for k, v in report["metrics"].items()]
    lines.append("  checks")
    lines += [f"    {name:<21} {state:<8} {detail}"
              for name, (state, detail) in report["checks"].items()]
    return "\n".join(lines) + "\n"


def parse_param(text: str) -> Any:
    """A param as MLflow stores it (a string) back to its value: ``"['a', 'b']"`` → list."""
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text
