"""Raw acquisition logs into the processed dataset.

For each condition of the plan, the log's latest complete attempt on the
current device (the last session's) gives the rows. A plan condition with no
complete attempt is an error that says how to resume; lines of the log that
break its format go to the quarantine (``bad_rows: quarantine``) or stop the
ingest (``bad_rows: error``, the default) — never dropped silently. Reads and writes
nothing: the ingest step (:mod:`eskin.steps.ingest`) does.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from eskin.data.plan import ScenePlan
from eskin.data.rawlog import LogContents, acquisition_sessions
from eskin.data.schema import DatasetError
from eskin.kinds import get_kind
from eskin.skin import PAPER_SKIN, AnySkin

BAD_ROW_POLICIES = ("error", "quarantine")


@dataclass
class Ingested:
    frame: pd.DataFrame
    metadata: dict
    quarantine: list[dict]
    # the live recordings' frames (live_frames); a file imported has none
    live: pd.DataFrame = field(default_factory=lambda: live_frames(None))


def check_policy(bad_rows: str) -> None:
    if bad_rows not in BAD_ROW_POLICIES:
        raise ValueError(f"ingest.bad_rows must be one of {BAD_ROW_POLICIES}, got {bad_rows!r}")


def ingest_contents(contents: LogContents, plan: ScenePlan, *, where: str, sha256: str,
                    bad_rows: str = "error") -> Ingested:
    """The dataset of ``plan`` from a raw log's parsed ``contents``
    (:func:`eskin.data.rawlog.read_log`); ``where`` (the log's path) and its ``sha256`` go
    into errors and the dataset's provenance. Reads nothing: the ingest step
    (:func:`eskin.steps.ingest.ingest_log`) reads the log."""
    check_policy(bad_rows)
    if contents.bad_lines and bad_rows == "error":
        first = contents.bad_lines[0]
        raise DatasetError(f"{first} ({len(contents.bad_lines)} malformed line(s) in the raw "
                           "log). Set ingest.bad_rows: quarantine to set them aside.")
    quarantine = [{"source": str(b.path), "line": b.line_number, "reason": b.reason,
                   "text": b.text} for b in contents.bad_lines]
    frame = _rows(contents, plan, where)
    last = acquisition_sessions(contents)[-1]
    metadata = {
        "scene": plan.name, "kind": plan.kind, "plan": plan.as_dict(),
        "device": last["device"], "simulator": last.get("simulator"),
        "source": {"kind": last.get("source"), "port": last.get("port"),
                   "path": where, "sha256": sha256,
                   "sessions": sorted({s for s in frame["session"].unique()}),
                   "frames_rejected_on_link": contents.frames_rejected},
    }
    return Ingested(frame, metadata, quarantine, live_frames(contents, plan.skin))


def _rows(contents: LogContents, plan: ScenePlan, path: str) -> pd.DataFrame:
    sessions = acquisition_sessions(contents)
    if not sessions:
        raise DatasetError(f"{path}: the raw log has no acquisition session; run "
                           f"`eskin acquire {plan.name}`")
    others = sorted({str(s.get("scene")) for s in contents.sessions} - {plan.name})
    if others:
        raise DatasetError(f"{path}: the raw log holds sessions of scene(s) {others} besides "
                           f"{plan.name}; each scene has its own log (data/raw/<scene>/)")
    device = sessions[-1]["device"]
    if device.get("terminals") != plan.skin.terminals:
        raise DatasetError(
            f"{path}: the raw log's board (device {device.get('id')}) has "
            f"{device.get('terminals')} terminals, but scene {plan.name} is on the "
            f"{plan.skin.describe()}: set scenes.{plan.name}.skin to the board's skin, or "
            f"acquire this scene again on the board built for it")
    attempts, missing = [], []
    for condition in plan.conditions:
        attempt = contents.completed.get(condition.key(device["id"], device["firmware"]))
        if attempt is None or len(attempt.frames) < plan.samples:
            missing.append(condition)
        else:
            attempts.append((condition, attempt))
    if missing:
        raise DatasetError(
            f"{path}: {len(missing)} of {len(plan.conditions)} planned conditions have no "
            f"complete recording on device {device['id']} (first: {missing[0].describe()}); "
            f"run `eskin acquire {plan.name}` to resume")
    n, k = plan.samples, len(attempts)
    channels = plan.skin.channels
    counts = np.empty((k * n, len(channels)))
    seq = np.empty(k * n, dtype=np.int64)
    t_ms = np.empty(k * n, dtype=np.int64)
    for i, (_, attempt) in enumerate(attempts):
        frames = attempt.frames[:n]
        counts[i * n:(i + 1) * n] = [f.counts for f in frames]
        seq[i * n:(i + 1) * n] = [f.seq for f in frames]
        t_ms[i * n:(i + 1) * n] = [f.t_ms for f in frames]
    data: dict[str, object] = {c: counts[:, j] for j, c in enumerate(channels)}
    labels = _labels([c for c, _ in attempts], plan.kind)
    data.update({name: np.repeat(values, n) for name, values in labels.items()})
    data["session"] = np.repeat([a.session["session"] for _, a in attempts], n)
    data["trial"] = np.repeat([a.condition["key"] for _, a in attempts], n)
    data["sample"] = np.tile(np.arange(n, dtype=np.int64), k)
    data["seq"] = seq
    data["t_ms"] = t_ms
    return pd.DataFrame(data)


LIVE_PROVENANCE = ["session", "device", "trial", "sample", "seq", "t_ms"]


def live_frames(contents: LogContents | None, skin: AnySkin = PAPER_SKIN) -> pd.DataFrame:
    """The frames of the log's live recordings (``eskin live --record``), in the order
    recorded: no labels (nobody said where the skin was pressed), so no training data,
    but a demonstration kept, to replay through a stack or to see how a board drifts."""
    attempts = [] if contents is None else sorted(
        (a for a in contents.completed.values() if a.session.get("mode") == "live"),
        key=lambda a: a.number)
    frames = [(a, i, f) for a in attempts for i, f in enumerate(a.frames)]
    data: dict[str, object] = {c: np.array([f.counts[j] for _, _, f in frames], dtype=float)
                               for j, c in enumerate(skin.channels)}
    data.update(session=[a.session["session"] for a, _, _ in frames],
                device=[a.session["device"]["id"] for a, _, _ in frames],
                trial=[a.condition["key"] for a, _, _ in frames],
                sample=np.array([i for _, i, _ in frames], dtype=np.int64),
                seq=np.array([f.seq for _, _, f in frames], dtype=np.int64),
                t_ms=np.array([f.t_ms for _, _, f in frames], dtype=np.int64))
    return pd.DataFrame(data, columns=[*skin.channels, *LIVE_PROVENANCE])


def _labels(conditions: list, kind: str) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for i, (force, x, y) in enumerate(get_kind(kind).contact_columns):
        out[force] = np.array([c.contacts[i].force for c in conditions])
        out[x] = np.array([c.contacts[i].x for c in conditions], dtype=np.int64)
        out[y] = np.array([c.contacts[i].y for c in conditions], dtype=np.int64)
    out["stretch"] = np.array([c.stretch for c in conditions])
    return out
