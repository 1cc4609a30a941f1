"""Live: a scene's whole trained stack on a board's stream, frame by frame.

:class:`SkinStack` is the one object a robot loop needs: the scene's featurizer and its
task models (stretch, contact, location, force), loaded from the workspace with every
file's md5 checked against dvc.lock, and ``predict(counts)`` from the 20 channels to
the estimates. :func:`live_estimates` runs it on a :class:`~eskin.device.link.SerialLink`
that streams (``STREAM ON``): a tare first (frames with nothing pressed, whose offset from
the training data's rest reading is taken off every frame after), then one estimate per
frame, carrying the board's ``seq`` and ``t_ms``; a lost frame or a damaged line is
reported where it happened and never predicted.

A single-force stack detects contact, and locates and weighs a contact only where it
detects one (elsewhere x and y are NaN and the force 0); stretch is estimated on every
frame. A two-force stack always has two contacts: x1, y1, x2, y2, force1, force2.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml
from threadpoolctl import ThreadpoolController

from eskin.catalog import TASK_NAMES, features_path, featurizer_path, model_path, processed_path
from eskin.data.schema import CHANNELS, read_metadata
from eskin.errors import EskinError
from eskin.learn import load_models

TARE_FRAMES = 100  # about 1.2 s of the stream at the board's 12 ms frame period
# A few frames are too little work to share between OpenMP threads (gradient boosting):
# waking them costs more than they save, and much more when the other core is busy
# (harness/live_latency.py, single force with a bench running: per-frame p99 149 ms on
# two threads, 18 ms on one). Batches up to this many rows are predicted on one thread.
ONE_THREAD_ROWS = 64
_THREADS = ThreadpoolController()


class StackError(EskinError, ValueError):
    """No stack to load, or a stack that does not fit the board."""


@dataclass
class SkinStack:
    """A scene's trained models, as one estimator from the 20 channels to the estimates."""

    scene: str
    kind: str
    featurizer: Any
    models: dict[str, dict[str, Any]]          # task → target → fitted estimator
    skipped: dict[str, str] = field(default_factory=dict)  # task → why it has no model
    device: dict | None = None                 # the board the training data came from
    rest: np.ndarray | None = None             # training rest reading (counts), for a tare

    # ------------------------------------------------------------ loading

    @classmethod
    def from_workspace(cls, scene: str, root: Path = Path(".")) -> SkinStack:
        """The stack ``dvc repro`` trained for ``scene``, each file checked against the md5
        dvc.lock records for it (a model file is code: only the recorded one is loaded)."""
        root = Path(root)
        recorded = _locked_md5s(root)
        features = root / features_path(scene)
        if not features.exists():
            raise StackError(f"no trained stack for scene {scene!r} ({features} is missing): "
                             f"run `dvc repro` (or `eskin featurize {scene}` and "
                             f"`eskin train {scene} <task>`)")
        meta = read_metadata(features)

        def load_recorded(path: Path):
            if not (root / path).exists():
                raise StackError(f"{path} is missing: run `dvc repro` (or `dvc checkout`)")
            md5 = recorded.get(path.as_posix())
            if md5 is None:
                raise StackError(f"{path} is not in dvc.lock: run `dvc repro`")
            return load_models(root / path, md5)

        featurizer = load_recorded(featurizer_path(scene))
        models, skipped = {}, {}
        for task in TASK_NAMES:
            loaded = load_recorded(model_path(scene, task))
            if "skipped" in loaded:
                skipped[task] = loaded["skipped"]
            else:
                models[task] = loaded
        rest = None
        processed = root / processed_path(scene)
        if processed.exists():
            rest = rest_reading(pd.read_parquet(processed))
        return cls(scene, meta["kind"], featurizer, models, skipped, meta.get("device"), rest)

    @classmethod
    def from_registry(cls, scene: str, alias: str, root: Path = Path(".")) -> SkinStack:
        """The stack whose task models carry the MLflow alias ``alias`` (``champion``:
        ``client.set_registered_model_alias("single_force.force", "champion", 3)``).
        Each task's file is found by the md5 its version recorded, in the workspace or
        DVC's cache, and checked before it is loaded, as ``eskin reproduce`` does; all
        must come from the same features version."""
        from eskin import tracking
        from eskin.registry import versioned_file

        client = tracking.connect()
        versions = [client.get_model_version_by_alias(model.name, alias)
                    for model in client.search_registered_models(f"name LIKE '{scene}.%'")
                    # LIKE's "_" matches any character, and scene names have them
                    if model.name.startswith(f"{scene}.") and alias in (model.aliases or {})]
        by_task = {v.tags.get("eskin.task"): v for v in versions}
        if not by_task:
            raise StackError(f"no registered model of scene {scene!r} has the alias {alias!r}: "
                             f"set one with MlflowClient().set_registered_model_alias("
                             f"'{scene}.force', '{alias}', <version>)")
        features_md5 = {v.tags.get("eskin.features_md5") for v in by_task.values()}
        if len(features_md5) != 1:
            raise StackError(f"the {alias!r} models of {scene} were trained on different "
                             f"features versions ({', '.join(sorted(map(str, features_md5)))}): "
                             "give the alias to versions of one training")
        features = versioned_file(root, features_path(scene), features_md5.pop(),
                                  f"features of {scene}")
        meta = read_metadata(features)
        models, skipped = {}, {}
        for task in TASK_NAMES:
            version = by_task.get(task)
            if version is None:
                skipped[task] = f"no {task} model has the alias {alias!r}"
                continue
            md5 = version.tags["eskin.model_md5"]
            models[task] = load_models(versioned_file(root, model_path(scene, task), md5,
                                                      f"{version.name} v{version.version}"), md5)
        processed = versioned_file(root, processed_path(scene), meta["dataset"]["md5"],
                                   f"dataset of {scene}")
        return cls(scene, meta["kind"], _featurizer_for(scene, meta, features, root),
                   models, skipped, meta.get("device"), rest_reading(pd.read_parquet(processed)))

    # ------------------------------------------------------------ predicting

    @property
    def columns(self) -> list[str]:
        if self.kind == "single_force":
            return ["stretch", "contact", "contact_probability", "x", "y", "force"]
        return ["stretch", "x1", "y1", "x2", "y2", "force1", "force2"]

    def predict(self, counts) -> pd.DataFrame:
        """Estimates for each row of ``counts`` (n × 20 channel readings, x1..x10 then
        y1..y10, in the units the stack was trained on)."""
        values = np.atleast_2d(np.asarray(counts, dtype=np.float64))
        if values.shape[1] != len(CHANNELS):
            raise ValueError(f"a frame has {len(CHANNELS)} channels, got {values.shape[1]}")
        if len(values) <= ONE_THREAD_ROWS:
            with _THREADS.limit(limits=1, user_api="openmp"):
                return self._predict(values)
        return self._predict(values)

    def _predict(self, values: np.ndarray) -> pd.DataFrame:
        X = pd.DataFrame(values, columns=CHANNELS)
        features = pd.DataFrame(np.asarray(self.featurizer.transform(X), dtype=np.float64),
                                columns=CHANNELS)
        n = len(features)
        out = pd.DataFrame(index=range(n))
        out["stretch"] = self._regress("stretch", "stretch", features)
        if self.kind != "single_force":
            located = self._each("localise", features)
            weighed = self._each("force", features)
            for name in ("x1", "y1", "x2", "y2"):
                out[name] = located.get(name, np.full(n, np.nan))
            for name in ("force1", "force2"):
                out[name] = weighed.get(name, np.full(n, np.nan))
            return out
        contact, probability = self._detect(features)
        out["contact"] = contact
        out["contact_probability"] = probability
        out["x"], out["y"] = np.full(n, np.nan), np.full(n, np.nan)
        out["force"] = np.zeros(n)
        if contact.any():
            touched = features[contact]
            located = self._each("localise", touched)
            for name in ("x", "y"):
                if name in located:
                    out.loc[contact, name] = located[name]
            out.loc[contact, "force"] = self._regress("force", "force", touched)
        return out

    def _each(self, task: str, features: pd.DataFrame) -> dict[str, np.ndarray]:
        return {target: np.asarray(model.predict(features), dtype=np.float64)
                for target, model in self.models.get(task, {}).items()}

    def _regress(self, task: str, target: str, features: pd.DataFrame) -> np.ndarray:
        model = self.models.get(task, {}).get(target)
        if model is None:
            return np.full(len(features), np.nan)
        return np.asarray(model.predict(features), dtype=np.float64)

    def _detect(self, features: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
        model = self.models.get("detect", {}).get("contact")
        n = len(features)
        if model is None:  # no detector (a scene without contact-free samples): always
            return np.ones(n, dtype=bool), np.full(n, np.nan)
        contact = np.asarray(model.predict(features)).astype(bool)
        if hasattr(model, "predict_proba"):
            classes = list(model.classes_)
            probability = model.predict_proba(features)[:, classes.index(True)]
        else:  # the paper's SVM gives no probability
            probability = np.full(n, np.nan)
        return contact, probability

    # ------------------------------------------------------------ fitting the board

    def check_board(self, device_id: str) -> None:
        """A stack trained on one board's data reads another's wrong (every terminal has
        its own baseline and gain): refuse it, saying what to do."""
        trained_on = (self.device or {}).get("id")
        if trained_on is not None and trained_on != device_id:
            raise StackError(f"the {self.scene} stack was trained on device {trained_on}, but "
                             f"the board says it is {device_id}: acquire and train on this "
                             "board (or pass --any-device to use it anyway)")


def rest_reading(frame: pd.DataFrame) -> np.ndarray | None:
    """The training data's reading with nothing pressed, at the lowest stretch: what a tare
    takes a live board's offset from. None for a scene without such samples."""
    from eskin.features import baseline_rows

    rows = baseline_rows(frame)
    if not rows.any():
        return None
    return frame.loc[rows, CHANNELS].to_numpy(dtype=np.float64).mean(axis=0)


def _featurizer_for(scene: str, meta: dict, features: Path, root: Path):
    """The featurizer that made ``features``: ``raw`` is the identity; a fitted one is the
    workspace's, if the workspace's features are these (their md5s agree)."""
    from eskin.data.schema import md5_file
    from eskin.features import make_featurizer

    method = meta["featurize"]["method"]
    if method == "raw":
        return make_featurizer("raw").fit(pd.DataFrame([[0.0] * len(CHANNELS)],
                                                       columns=CHANNELS))
    workspace = root / features_path(scene)
    if workspace.exists() and md5_file(workspace) == md5_file(features):
        relative = featurizer_path(scene)
        return load_models(root / relative, _locked_md5s(root)[relative.as_posix()])
    raise StackError(f"the registered models of {scene} were trained on {method!r} features, "
                     "whose fitted featurizer is in the workspace only while its features are "
                     "these: check out that commit (git checkout, dvc checkout)")


def _locked_md5s(root: Path) -> dict[str, str]:
    lock = root / "dvc.lock"
    if not lock.exists():
        raise StackError(f"{lock} is missing: run `dvc repro` to train the stack")
    stages = (yaml.safe_load(lock.read_text()) or {}).get("stages", {})
    return {out["path"]: out["md5"] for stage in stages.values()
            for out in stage.get("outs", []) if "md5" in out}


# ---------------------------------------------------------------- the stream


@dataclass
class Tare:
    """A live board's offset from the training rest reading, taken with nothing pressed,
    and taken off every frame after. ``drift`` is how far, in counts (the largest channel),
    the untouched reading has moved since (a running average over ``drift_frames`` of the
    frames without contact; a stretch moves it too). Without a tare (:meth:`none`) there
    is nothing to measure drift or change from: both are None."""

    offset: np.ndarray
    reading: np.ndarray | None
    drift_frames: int = 200
    _recent: np.ndarray = None  # type: ignore[assignment]  # starts at the tare's reading

    @classmethod
    def take(cls, frames: np.ndarray, rest: np.ndarray | None) -> Tare:
        reading = np.asarray(frames, dtype=np.float64).mean(axis=0)
        offset = reading - rest if rest is not None else np.zeros_like(reading)
        return cls(offset, reading, _recent=reading.copy())

    @classmethod
    def none(cls) -> Tare:
        return cls(np.zeros(len(CHANNELS)), None)

    def apply(self, counts: np.ndarray) -> np.ndarray:
        return np.asarray(counts, dtype=np.float64) - self.offset

    def note_rest(self, counts: np.ndarray) -> None:
        if self.reading is None:
            return
        weight = 1.0 / self.drift_frames
        self._recent = (1 - weight) * self._recent + weight * np.asarray(counts, np.float64)

    @property
    def drift(self) -> float | None:
        if self.reading is None:
            return None
        return round(float(np.max(np.abs(self._recent - self.reading))), 3)


def _number(value: Any) -> Any:
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (float, np.floating)):
        return None if math.isnan(value) else round(float(value), 6)
    if isinstance(value, (np.integer,)):
        return int(value)
    return value


def live_estimates(stack: SkinStack, batches: Iterable[list], *,
                   tare_frames: int = TARE_FRAMES, with_change: bool = False,
                   notify: Callable[[str], object] = lambda message: None
                   ) -> Iterator[dict[str, Any]]:
    """One record per stream event, in order: an estimate per frame (``seq``, ``t_ms``,
    the stack's columns and the drift since the tare), ``{"gap": ...}`` for lost frames,
    ``{"rejected": ...}`` for a line that failed its check. The first ``tare_frames``
    frames are the tare (nothing may be pressed), reported once as ``{"tare": ...}``
    (``tare_frames=0``: no tare). ``batches`` are the events as they arrived: a batch's
    frames are predicted together, as a scikit-learn call costs milliseconds whatever
    its rows, so the stack keeps up with the board. ``with_change``: each estimate also
    carries ``change_counts``, the 20 channels' change since the tare (the live view's
    bars)."""
    from eskin.device.host import Junk, StreamFrame, StreamGap
    from eskin.device.link import StreamOverflow

    taring: list[np.ndarray] = []
    tare = Tare.none() if tare_frames <= 0 else None
    for batch in batches:
        records: list[dict[str, Any] | None] = []
        pending: list[tuple[int, Any]] = []  # (index in records, frame) to predict
        for event in batch:
            if isinstance(event, StreamGap):
                records.append({"gap": {"expected": event.expected, "got": event.got,
                                        "lost": (event.got - event.expected) % 2**32}})
            elif isinstance(event, Junk):
                records.append({"rejected": event.error.reason})
            elif isinstance(event, StreamOverflow):
                records.append({"overflow": {"dropped": event.dropped}})
            elif isinstance(event, StreamFrame):
                counts = np.asarray(event.frame.counts, dtype=np.float64)
                if tare is not None:
                    pending.append((len(records), event.frame))
                    records.append(None)
                    continue
                taring.append(counts)
                if len(taring) == tare_frames:
                    tare = Tare.take(np.array(taring), stack.rest)
                    notify(f"tared on {tare_frames} frames")
                    records.append({"tare": {"frames": tare_frames, "offset_counts":
                                             [round(float(v), 3) for v in tare.offset]}})
        if pending:
            counts = np.array([frame.counts for _, frame in pending], dtype=np.float64)
            estimates = stack.predict(tare.apply(counts))
            contact = estimates["contact"].to_numpy() if "contact" in estimates else None
            for row, (at, frame) in enumerate(pending):
                if contact is not None and not contact[row]:
                    tare.note_rest(counts[row])
                record = {"seq": frame.seq, "t_ms": frame.t_ms}
                record.update({name: _number(estimates[name].iloc[row])
                               for name in stack.columns})
                record["drift_counts"] = tare.drift
                if with_change:
                    record["change_counts"] = None if tare.reading is None else [
                        round(float(v), 1) for v in counts[row] - tare.reading]
                records[at] = record
        yield from records


def json_line(record: dict[str, Any]) -> str:
    return json.dumps(record, separators=(",", ":"), allow_nan=False)


def stream_events(link, *, reconnect_s: float = 30.0, timeout_s: float | None = None,
                  notify: Callable[[str], object] = print) -> Iterator:
    """The board's stream as batches of events (:meth:`SerialLink.stream`), started, and
    started again after a restart or a lost link reopened (as acquisition reopens it,
    within ``reconnect_s``). Stops the stream when closed."""
    from eskin.device.link import BoardReset, LinkError

    link.start_stream()
    try:
        while True:
            try:
                yield from link.stream(timeout_s=timeout_s)
            except BoardReset:
                notify(f"{link.port}: the board restarted; streaming again")
                link.start_stream()
            except LinkError as err:
                notify(f"{link.port}: {err}")
                link.reopen(budget_s=reconnect_s, notify=notify)
                link.start_stream()
    finally:
        try:
            link.stop_stream()
        except (LinkError, OSError):
            pass  # the link is gone: nothing to stop


class LineBroadcast:
    """JSON lines for other programs: a TCP server on 127.0.0.1 that sends every line to
    every connected client. Each client has a bounded backlog (``max_backlog`` bytes): one
    that does not read is dropped, and the live loop never waits for anybody."""

    def __init__(self, port: int = 0, *, max_backlog: int = 1 << 20,
                 notify: Callable[[str], object] = lambda message: None) -> None:
        import socket

        self._server = socket.create_server(("127.0.0.1", port))
        self._server.setblocking(False)
        self.port = self._server.getsockname()[1]
        self.max_backlog = max_backlog
        self.notify = notify
        self._clients: dict[Any, bytearray] = {}

    def _accept(self) -> None:
        while True:
            try:
                client, address = self._server.accept()
            except BlockingIOError:
                return
            client.setblocking(False)
            self._clients[client] = bytearray()
            self.notify(f"client {address[0]}:{address[1]} connected")

    def send(self, line: str) -> None:
        self._accept()
        data = (line + "\n").encode()
        for client, backlog in list(self._clients.items()):
            backlog += data
            try:
                sent = client.send(backlog)
                del backlog[:sent]
            except BlockingIOError:
                pass
            except OSError:  # the client went away
                self._drop(client, "disconnected")
                continue
            if len(backlog) > self.max_backlog:
                self._drop(client, f"dropped: more than {self.max_backlog} bytes unread")

    def _drop(self, client, why: str) -> None:
        self._clients.pop(client, None)
        try:
            self.notify(f"client {client.getpeername()[1]} {why}")
        except OSError:
            self.notify(f"a client {why}")
        client.close()

    def close(self) -> None:
        for client in list(self._clients):
            client.close()
        self._clients.clear()
        self._server.close()

    def __enter__(self) -> LineBroadcast:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
