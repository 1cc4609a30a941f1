"""The stack: a scene's whole trained model set, as one object from the skin's channels
to the estimates — what a robot loop holds.

:class:`SkinStack` is the scikit-learn stack: the scene's featurizer and its task models
(stretch, contact, location, force), loaded from the workspace with every file's md5
checked against dvc.lock (or from the MLflow registry by alias:
:func:`eskin.tracking.registry.stack_from_registry`, which imports MLflow; this module
does not). :class:`ExportedStack` is the same stack as one ONNX file
(:mod:`eskin.deploy.export`), run by onnxruntime. Both have ``predict(counts)`` from
n rows of channel readings (the skin's channels, in its order: x terminals then y on a
row/column skin) to a DataFrame of estimates. A stack knows its skin (:attr:`SkinStack.skin`):
the one its training data were taken on, recorded in the ONNX file beside it.

A one-contact stack detects contact, and locates and weighs a contact only where it
detects one (elsewhere x and y are NaN and the force 0); stretch is estimated on every
frame. A two-contact stack counts the contacts (``contacts``: 0, 1 or 2, and ``contact``,
whether any presses) where its scene was recorded with fewer than two on some
conditions (``contact_counts``), and gives the position and force of that many (an
absent contact: NaN and 0 N). Trained on the paper's plan, which presses both on every
sample, it has nothing to count from and always gives two: x1, y1, x2, y2, force1,
force2 — or x1, y1, x2, y2 and force, their total, where the training recording gave
only that (the kind's total-force variant).
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml
from threadpoolctl import ThreadpoolController

from eskin.catalog import TASK_NAMES, features_path, featurizer_path, model_path, processed_path
from eskin.data.schema import contact_mask, dataset_kind, dataset_skin, read_metadata
from eskin.errors import EskinError
from eskin.kinds import get_kind
from eskin.learning.saved import load_models
from eskin.skin import AnySkin, skin_from_dict

# A few frames are too little work to share between OpenMP threads (gradient boosting):
# waking them costs more than they save, and much more when the other core is busy
# (harness/live_latency.py, single force with a bench running: per-frame p99 149 ms on
# two threads, 18 ms on one). Batches up to this many rows are predicted on one thread.
ONE_THREAD_ROWS = 64


@functools.cache
def _threads() -> ThreadpoolController:
    """The thread pools of the libraries loaded when a stack first predicts: made then,
    after its models loaded scikit-learn's OpenMP library. One made at import held no
    OpenMP library, and its one-thread limit did nothing (issue 57: at load 15, 267 ms
    a frame against 79 ms with it)."""
    return ThreadpoolController()


class StackError(EskinError, ValueError):
    """No stack to load, or a stack that does not fit the board."""


@dataclass
class SkinStack:
    """A scene's trained models, as one estimator from the skin's channels to the
    estimates."""

    scene: str
    kind: str
    skin: AnySkin                              # the skin its training data were taken on
    featurizer: Any
    models: dict[str, dict[str, Any]]          # task → target → fitted estimator
    skipped: dict[str, str] = field(default_factory=dict)  # task → why it has no model
    device: dict | None = None                 # the board the training data came from
    rest: RestTable | None = None              # training rest readings (counts), for a tare

    # ------------------------------------------------------------ loading

    @classmethod
    def from_workspace(cls, scene: str, root: Path = Path("."),
                       recorded: dict[str, str] | None = None) -> SkinStack:
        """The stack ``dvc repro`` trained for ``scene``, each file checked against the md5
        dvc.lock records for it (a model file is code: only the recorded one is loaded), or
        the one ``recorded`` gives (the train stage's, before DVC records its outputs)."""
        root = Path(root)
        recorded = locked_md5s(root) if recorded is None else recorded
        features = root / features_path(scene)
        if not features.exists():
            raise StackError(f"no trained stack for scene {scene!r} ({features} is missing): "
                             f"run `dvc repro` (or `eskin featurize {scene}` and "
                             f"`eskin train {scene} <task>`)")
        meta = read_metadata(features)
        skin = dataset_skin(features)

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
            rest = rest_readings(pd.read_parquet(processed), skin)
        return cls(scene, dataset_kind(features).name, skin, featurizer, models, skipped,
                   meta.get("device"), rest)

    # ------------------------------------------------------------ predicting

    @property
    def columns(self) -> list[str]:
        return get_kind(self.kind).stack_outputs(counted="detect" in self.models)

    def predict(self, counts) -> pd.DataFrame:
        """Estimates for each row of ``counts`` (n × the skin's channels, in its order —
        x1..xR then y1..yC on a row/column skin — in the units the stack was trained on)."""
        values = frame_values(counts, self.scene, self.skin)
        if len(values) <= ONE_THREAD_ROWS:
            with _threads().limit(limits=1, user_api="openmp"):
                return self._predict(values)
        return self._predict(values)

    def _predict(self, values: np.ndarray) -> pd.DataFrame:
        channels = self.skin.channels
        X = pd.DataFrame(values, columns=channels)
        features = pd.DataFrame(np.asarray(self.featurizer.transform(X), dtype=np.float64),
                                columns=channels)
        n = len(features)
        out = pd.DataFrame(index=range(n))
        out["stretch"] = self._regress("stretch", "stretch", features)
        kind = get_kind(self.kind)
        if "contact" not in self.columns:  # two contacts on every frame: nothing counted
            located = self._each("localise", features)
            weighed = self._each("force", features)
            for name in kind.node_columns:
                out[name] = located.get(name, np.full(n, np.nan))
            for name in kind.force_columns:
                out[name] = weighed.get(name, np.full(n, np.nan))
            return out
        count, probability = self._detect(features, kind.detect_target)
        contact = count > 0
        out["contact"] = contact
        out["contact_probability"] = probability
        if "contacts" in self.columns:
            out["contacts"] = count.astype(np.float64)
        for name in kind.node_columns:
            out[name] = np.full(n, np.nan)
        for name in kind.force_columns:
            out[name] = np.zeros(n)
        if contact.any():
            touched = features[contact]
            located = self._each("localise", touched)
            for name in kind.node_columns:
                if name in located:
                    out.loc[contact, name] = located[name]
            for name in kind.force_columns:
                out.loc[contact, name] = self._regress("force", name, touched)
            # contact k is there where k or more press: an absent one is not placed
            for k, (x, y) in enumerate(kind.positions.values(), start=1):
                absent = contact & (count < k)
                out.loc[absent, [x, y]] = np.nan
                for force, weighs in kind.weighed_contacts.items():
                    if weighs == [x]:
                        out.loc[absent, force] = 0.0
        return out

    def _each(self, task: str, features: pd.DataFrame) -> dict[str, np.ndarray]:
        return {target: np.asarray(model.predict(features), dtype=np.float64)
                for target, model in self.models.get(task, {}).items()}

    def _regress(self, task: str, target: str, features: pd.DataFrame) -> np.ndarray:
        model = self.models.get(task, {}).get(target)
        if model is None:
            return np.full(len(features), np.nan)
        return np.asarray(model.predict(features), dtype=np.float64)

    def _detect(self, features: pd.DataFrame, target: str) -> tuple[np.ndarray, np.ndarray]:
        """How many contacts press in each row (a contact detector's 0 or 1), and the
        probability that any does."""
        model = self.models.get("detect", {}).get(target)
        n = len(features)
        if model is None:  # no detector (a scene without contact-free samples): always
            return np.ones(n, dtype=np.int64), np.full(n, np.nan)
        count = np.asarray(model.predict(features)).astype(np.int64)
        if hasattr(model, "predict_proba"):
            # the classes with a contact (one column with one contact: its value exactly)
            pressed = np.asarray(model.classes_).astype(np.int64) > 0
            probability = model.predict_proba(features)[:, pressed].sum(axis=1)
        else:  # the paper's SVM gives no probability
            probability = np.full(n, np.nan)
        return count, probability

    def check_board(self, device_id: str) -> None:
        check_board(self.scene, self.device, device_id)


def frame_values(counts, scene: str, skin: AnySkin) -> np.ndarray:
    """``counts`` as n rows of float64, each as wide as ``skin`` has channels (else one
    line saying which skin the stack reads)."""
    values = np.atleast_2d(np.asarray(counts, dtype=np.float64))
    if values.shape[1] != skin.terminals:
        raise ValueError(f"the {scene} stack is for the {skin.describe()}: a frame has "
                         f"{skin.terminals} channels, got {values.shape[1]}")
    return values


def check_board(scene: str, device: dict | None, device_id: str) -> None:
    """A stack trained on one board's data reads another's wrong (every terminal has its
    own baseline and gain): refuse it, saying what to do."""
    trained_on = (device or {}).get("id")
    if trained_on is not None and trained_on != device_id:
        raise StackError(f"the {scene} stack was trained on device {trained_on}, but "
                         f"the board says it is {device_id}: acquire and train on this "
                         "board (or pass --any-device to use it anyway)")


@dataclass
class ExportedStack:
    """The stack as one ONNX file (``eskin export``, :mod:`eskin.deploy.export`), run by
    onnxruntime: the same :meth:`predict` as :class:`SkinStack`, a tenth of its time per
    frame or less (``make bench``), and nothing of eskin's training side needed to load it.
    The file names its scene, kind, board and rest reading in its metadata, and its skin
    (``eskin.skin``) when it is not the paper's, whose stacks predate it byte for byte."""

    scene: str
    kind: str
    skin: AnySkin
    device: dict | None
    rest: RestTable | None
    columns: list[str]
    session: Any

    @classmethod
    def from_file(cls, path: Path) -> ExportedStack:
        import onnxruntime

        path = Path(path)
        if not path.exists():
            raise StackError(f"{path} is missing: run `dvc repro` (or `eskin export <scene>`)")
        options = onnxruntime.SessionOptions()
        # One frame at a time is too little work to share between threads (as ONE_THREAD_ROWS)
        options.intra_op_num_threads = options.inter_op_num_threads = 1
        try:
            session = onnxruntime.InferenceSession(str(path), options,
                                                   providers=["CPUExecutionProvider"])
        except Exception as error:  # onnxruntime raises its own, unexported, classes
            raise StackError(f"{path} is not a stack onnxruntime can load: {error}") from None
        meta = session.get_modelmeta().custom_metadata_map
        if "eskin.scene" not in meta:
            raise StackError(f"{path} is not an eskin stack (it has no eskin.scene metadata)")
        rest = json.loads(meta.get("eskin.rest_table", "null"))
        lowest = json.loads(meta.get("eskin.rest_counts", "null"))
        if rest is None and lowest is not None:
            # a stack exported before the table: its lowest stretch's reading alone
            rest = {"stretch": [1.0], "counts": [lowest]}
        skin = skin_from_dict(json.loads(meta.get("eskin.skin", "null")))
        return cls(meta["eskin.scene"], meta["eskin.kind"], skin,
                   json.loads(meta["eskin.device"]),
                   None if rest is None else RestTable.from_dict(rest),
                   json.loads(meta["eskin.columns"]), session)

    def predict(self, counts) -> pd.DataFrame:
        values = np.ascontiguousarray(frame_values(counts, self.scene, self.skin))
        if not np.isfinite(values).all():  # as the scikit-learn stack refuses them
            raise ValueError("a frame has a reading that is NaN or infinite")
        return pd.DataFrame(dict(zip(self.columns, self.session.run(self.columns,
                                                                     {"counts": values}),
                                     strict=True)))

    def check_board(self, device_id: str) -> None:
        check_board(self.scene, self.device, device_id)


@dataclass(frozen=True)
class RestTable:
    """The training data's readings with nothing pressed, one row per stretch the scene was
    recorded at (ascending): what a tare takes a live board's offset from, and what live
    expects an untouched skin to read at a stretch (between two recorded stretches,
    interpolated channel by channel; beyond them, extrapolated from the nearest two)."""

    stretch: np.ndarray  # (k,)
    counts: np.ndarray   # (k, channels)

    def at(self, stretch: float | None = None) -> np.ndarray:
        """The untouched reading at ``stretch`` (None, NaN or one row: the lowest's); beyond
        the recorded stretches, the nearest segment's line."""
        if stretch is None or not np.isfinite(stretch) or len(self.stretch) == 1:
            return self.counts[0]
        at = int(np.clip(np.searchsorted(self.stretch, stretch) - 1, 0, len(self.stretch) - 2))
        share = (stretch - self.stretch[at]) / (self.stretch[at + 1] - self.stretch[at])
        return self.counts[at] + share * (self.counts[at + 1] - self.counts[at])

    def stretch_of(self, reading: np.ndarray, *,
                   ignore: np.ndarray | None = None) -> float | None:
        """The stretch an untouched ``reading`` is at: each channel whose untouched reading
        rises with stretch says its own (inverting :meth:`at`), and the median of them is
        taken, so that a press, which raises a few channels, does not move it; channels in
        ``ignore`` (a contact's: live's baseline) say nothing, unless fewer than three
        would be left. None with one row, or no channel that rises."""
        if len(self.stretch) == 1:
            return None
        says = np.all(np.diff(self.counts, axis=0) > 0, axis=0)
        if ignore is not None and (says & ~ignore).sum() >= 3:
            says = says & ~ignore
        rising = np.flatnonzero(says)
        if not len(rising):
            return None
        # every rising channel at once (live calls this on each frame): its segment is the
        # one np.searchsorted(column, value) - 1 names, kept within the table
        columns = self.counts[:, rising]
        values = np.asarray(reading, dtype=np.float64)[rising]
        at = np.clip((columns < values).sum(axis=0) - 1, 0, len(self.stretch) - 2)
        channel = np.arange(len(rising))
        low, high = columns[at, channel], columns[at + 1, channel]
        share = (values - low) / (high - low)
        estimates = self.stretch[at] + share * (self.stretch[at + 1] - self.stretch[at])
        return float(np.median(estimates))

    def as_dict(self) -> dict[str, list]:
        return {"stretch": [float(v) for v in self.stretch],
                "counts": [[float(v) for v in row] for row in self.counts]}

    @classmethod
    def from_dict(cls, values: dict[str, list]) -> RestTable:
        return cls(np.asarray(values["stretch"], dtype=np.float64),
                   np.asarray(values["counts"], dtype=np.float64))


def rest_readings(frame: pd.DataFrame, skin: AnySkin) -> RestTable | None:
    """The training data's readings (of ``skin``'s channels) with nothing pressed, at each
    stretch recorded. None for a scene without such samples."""
    free = frame.loc[~contact_mask(frame)]
    if free.empty:
        return None
    means = free.groupby("stretch", sort=True)[skin.channels].mean()
    return RestTable(means.index.to_numpy(dtype=np.float64),
                     means.to_numpy(dtype=np.float64))


def featurizer_for(scene: str, meta: dict, features: Path, skin: AnySkin, root: Path):
    """The featurizer that made ``features``: ``raw`` is the identity; a fitted one is the
    workspace's, if the workspace's features are these (their md5s agree)."""
    from eskin.data.schema import md5_file
    from eskin.learning.features import make_featurizer

    method = meta["featurize"]["method"]
    if method == "raw":
        return make_featurizer("raw").fit(pd.DataFrame([[0.0] * skin.terminals],
                                                       columns=skin.channels))
    workspace = root / features_path(scene)
    if workspace.exists() and md5_file(workspace) == md5_file(features):
        relative = featurizer_path(scene)
        return load_models(root / relative, locked_md5s(root)[relative.as_posix()])
    raise StackError(f"the registered models of {scene} were trained on {method!r} features, "
                     "whose fitted featurizer is in the workspace only while its features are "
                     "these: check out that commit (git checkout, dvc checkout)")


def locked_md5s(root: Path) -> dict[str, str]:
    lock = root / "dvc.lock"
    if not lock.exists():
        raise StackError(f"{lock} is missing: run `dvc repro` to train the stack")
    # libyaml's loader: the pure-Python one took 0.4 s a read of a 2,800-line lock
    stages = (yaml.load(lock.read_text(), Loader=yaml.CSafeLoader) or {}).get("stages", {})
    return {out["path"]: out["md5"] for stage in stages.values()
            for out in stage.get("outs", []) if "md5" in out}
