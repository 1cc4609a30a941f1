"""params.yaml: the one place every knob of the pipeline lives, checked once at load, read
as typed sections; bench/params.yaml and stress/params.yaml: the same for `make bench` and
`make stress` (DVC projects of their own, so their knobs stay out of `dvc exp show`).

:func:`load_params` validates a whole file against its declared schema
(pydantic, strict: types, ranges, required keys, no unknown keys) before any
step runs, so a typo or a wrong type is one line naming the file, the key, the value
and what is allowed — never a traceback after an hour of acquisition, and
never a value silently truncated or replaced by a default.
"""

from __future__ import annotations

import atexit
import contextlib
import difflib
import json
import os
import re
import sys
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import (
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    ValidationError,
    WrapValidator,
    create_model,
    field_validator,
    model_validator,
)

from eskin.catalog import SCHEMES, SOURCES, TASK_NAMES
from eskin.errors import EskinError
from eskin.kinds import KIND_NAMES, KINDS, Kind
from eskin.skin import PAPER_SKIN, AnySkin, skin_from_dict

DEFAULT_PARAMS = Path("params.yaml")
# The subprojects' own default params files (bench/dvc.yaml, stress/dvc.yaml), from the
# project root, where their stages run.
BENCH_PARAMS = Path("bench/params.yaml")
STRESS_PARAMS = Path("stress/params.yaml")
# Set to a directory, each process notes there the params keys it read after validation
# (tests/test_stage_deps.py compares them with each DVC stage's declared params).
TRACE_ENV = "ESKIN_PARAMS_TRACE"


class ParamsError(EskinError, ValueError):
    """params.yaml cannot be used as written; the message names the key."""


# ------------------------------------------------------------------ schema

class _Section(BaseModel):
    # strict: "ten" is not 10, 2.5 is not 2, 1.0 is not [1.0]; finite numbers only.
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)


def _as_written(value: Any, handler: Any) -> Any:
    """A number checked as a float but kept as written: ``40`` stays the int 40, so the
    values the library reads (and MLflow logs) are the file's, as before the model."""
    checked = handler(value)
    return value if type(value) is int else checked


def _real(**constraints: Any) -> Any:
    """A float field (strict: no strings, no bools) that keeps an int as written."""
    return Annotated[float, Field(**constraints), WrapValidator(_as_written)]


Real = _real()
Probability = _real(ge=0, lt=1)
Positive = _real(gt=0)
NonNegative = _real(ge=0)
Count = Annotated[int, Field(ge=1)]
Seed = Annotated[int, Field(ge=0)]
Scheme = Literal[SCHEMES]  # type: ignore[valid-type]
TaskName = Literal[TASK_NAMES]  # type: ignore[valid-type]
Backend = Literal["loky", "threading", "sequential", "dask"]
Jobs = Annotated[int, Field(ge=-1)]



class Sim(_Section):
    """The simulated skin (eskin.device.physics.SkinParams reads it; a test checks that
    both name the same keys). Every key required: no built-in default stands in for a
    missing line. Declared here, not imported from the physics, so that a physics edit
    reruns acquisition and what follows from its data, not every stage that reads params."""

    seed: Seed
    baseline_pf: Positive
    baseline_spread: NonNegative
    stretch_sensitivity_spread: NonNegative
    strain_max: _real(gt=0, lt=1)
    force_half_n: Positive
    force_hill: Positive
    stretch_stiffening: Real
    reach_nodes: Annotated[int, Field(ge=0)]
    placement_sd_nodes: NonNegative
    # below half a pitch, so that an indenter stays on its node
    placement_max_nodes: _real(lt=0.5)
    node_sensitivity_spread: NonNegative
    seating_force_n: NonNegative
    seating_variation: NonNegative
    noise_pf: NonNegative
    drift_offset_pf: NonNegative
    drift_time_constant_s: Positive
    creep_fraction: NonNegative
    creep_time_s: Positive
    cav424_ref_pf: Positive
    cav424_gain_v: Positive
    cav424_gain_spread: NonNegative
    cav424_offset_v: Real
    supply_v: Positive
    adc_bits: Annotated[int, Field(ge=1, le=16)]


class Faults(_Section):
    drop: Probability
    garbage: Probability
    reset: Probability
    stall: Probability
    vanish: Probability
    stall_s: NonNegative
    vanish_s: NonNegative
    seed: Seed
    log: str | None = None


class SimBoard(_Section):
    corrupt_fraction: Probability
    frame_period_ms: Count
    faults: Faults


class Acquire(_Section):
    """How every scene is acquired; where each scene's data comes from is its own."""

    indenters: Literal["person", "board"] = "person"
    rest_length_mm: Positive
    timeout_s: Positive
    reconnect_s: NonNegative
    max_jump_counts: Positive
    max_attempts: Count
    max_interruptions: Count


class Soak(_Section):
    corrupt_fraction: Probability
    faults: Faults
    timeout_s: Positive
    reconnect_s: NonNegative
    kill_at: list[_real(gt=0, lt=1)]


class Fuzz(_Section):
    examples: Count


class RowColumnSkin(_Section):
    """A row/column capacitive skin (eskin.skin.Skin): R × C terminals, R + C channels."""

    rows: Annotated[int, Field(ge=2, le=32)]
    columns: Annotated[int, Field(ge=2, le=32)]


class ChannelArraySkin(_Section):
    """N named channels read at once (eskin.skin.ChannelArray), pressed on a grid of
    positions: ``grid: [size_x, size_y]``, or the positions' coordinates in mm along each
    axis (``x_mm``, ``y_mm``), or both."""

    channels: Annotated[list[Annotated[str, Field(min_length=1)]], Field(min_length=1)]
    grid: Annotated[list[Annotated[int, Field(ge=1, le=64)]],
                    Field(min_length=2, max_length=2)] | None = None
    x_mm: Annotated[list[Real], Field(min_length=1, max_length=64)] | None = None
    y_mm: Annotated[list[Real], Field(min_length=1, max_length=64)] | None = None

    @model_validator(mode="after")
    def _positions(self) -> ChannelArraySkin:
        if self.grid is None and (self.x_mm is None or self.y_mm is None):
            raise ValueError("a channel array needs its press positions: grid: [nx, ny], "
                             "or x_mm and y_mm (each grid line's coordinate)")
        if len(set(self.channels)) != len(self.channels):
            raise ValueError("channel names must differ")
        try:
            skin_from_dict(self.model_dump(exclude_none=True))
        except ValueError as err:
            raise ValueError(str(err)) from None
        return self


def _skin_layout(value: Any) -> str:
    fields = value if isinstance(value, Mapping) else vars(value)
    return "channel_array" if "channels" in fields else "row_column"


SKIN_LAYOUTS = ("row_column", "channel_array")
SkinSpec = Annotated[
    Annotated[RowColumnSkin, Tag("row_column")] | Annotated[ChannelArraySkin,
                                                            Tag("channel_array")],
    Discriminator(_skin_layout)]


Source = Literal[SOURCES]  # type: ignore[valid-type]
# A scene name becomes a DVC stage name (acquire@<scene>, train@<scene>-<task>), a
# directory and an MLflow tag: letters, digits and underscores, starting with a letter.
SCENE_NAME = r"^[A-Za-z][A-Za-z0-9_]*$"
# The plan: what an acquired scene records; an import's labels come from its files.
PLAN_KEYS = ("stretches", "forces", "samples", "repeats", "nodes_x", "nodes_y")

# What an import's columns may give, in the kinds' own words: every kind's forces and
# nodes, each node also as a position in mm (``x_mm``: placed on the skin's grid).
FORCE_KEYS = tuple(dict.fromkeys(c for kind in KINDS.values() for c in kind.force_columns))
NODE_KEYS = tuple(dict.fromkeys(c for kind in KINDS.values() for c in kind.node_columns))
POSITION_KEYS = NODE_KEYS + tuple(f"{node}_mm" for node in NODE_KEYS)
FORCE_UNITS = {"N": 1.0, "mN": 1e-3}
TRIALS = ("labels", "file", "time")

Name = Annotated[str, Field(min_length=1)]
ImportColumns = create_model(
    "ImportColumns", __base__=_Section,
    __doc__="Which column of the files gives what (by the header's names): ``channels`` "
            "(a list, matched in order to the skin's channels, or a glob over the header; "
            "default the skin's channel names), the labels, ``time`` (s) and ``trial``.",
    channels=(Name | Annotated[list[Name], Field(min_length=1)] | None, None),
    **{key: (Name | None, None) for key in (*FORCE_KEYS, *POSITION_KEYS, "stretch", "time",
                                             "trial")})


class Import(_Section):
    """Where an import scene's files are and how to read them (docs/data.md#importing).

    ``path`` alone: one file in the paper's layout. With ``columns``: a file, a folder (its
    CSV and Parquet files) or a glob, read in sorted order, each column where the map says."""

    path: Name
    columns: ImportColumns | None = None  # type: ignore[valid-type]
    # A regex on each file's name; its named groups (x, y, or x_mm, y_mm; x1, …) label
    # every row of the file.
    position_from_name: Name | None = None
    force_unit: Literal[tuple(FORCE_UNITS)] = "N"  # type: ignore[valid-type]
    force_sign: Literal[1, -1] = 1  # -1: the sensor reads compression as negative
    # A contact is a force above this (N) after each file's rest offset is removed.
    contact_n: Positive | None = None
    # labels: a run of rows with the same labels; file: one per file; time: blocks of
    # trial_s seconds (columns.time). A trial column is columns.trial.
    trials: Literal[TRIALS] = "labels"  # type: ignore[valid-type]
    trial_s: Positive | None = None
    position_tolerance_mm: Positive | None = None  # default: a quarter of the finest pitch

    @model_validator(mode="after")
    def _consistent(self) -> Import:
        if self.columns is None:
            mapped = sorted(self.model_fields_set - {"path"})
            if mapped:
                raise ValueError(f"{mapped[0]} reads another instrument's files: set "
                                 "import.columns too (without it, import.path is one file "
                                 "in the paper's layout)")
            return self
        columns = self.columns
        if self.position_from_name is not None:
            try:
                groups = set(re.compile(self.position_from_name).groupindex)
            except re.error as err:
                raise ValueError(f"position_from_name is not a regular expression ({err})"
                                 ) from None
            unknown = sorted(groups - set(POSITION_KEYS))
            if unknown or not groups:
                raise ValueError(f"position_from_name names groups {unknown or 'none'}; its "
                                 f"named groups give positions: {', '.join(POSITION_KEYS)}")
            if self.contact_n is None:
                raise ValueError("position_from_name labels every row of a file with its "
                                 "position: set import.contact_n (N) to say which rows are "
                                 "presses")
        if columns.trial is not None and "trials" in self.model_fields_set:
            raise ValueError(f"columns.trial and trials: {self.trials} both say where trials "
                             "are; keep one")
        if self.trials == "time" and (self.trial_s is None or columns.time is None):
            raise ValueError("trials: time cuts the rows into blocks of trial_s seconds of "
                             "columns.time: set both")
        if self.trial_s is not None and self.trials != "time":
            raise ValueError("trial_s is the length of a trial under trials: time")
        return self

    def position_sources(self) -> dict[str, str]:
        """{position key (x, x_mm, …): where it comes from ("column" or "name")}."""
        named = set(re.compile(self.position_from_name).groupindex) \
            if self.position_from_name else set()
        out = {key: "name" for key in POSITION_KEYS if key in named}
        columns = self.columns
        out.update({key: "column" for key in POSITION_KEYS
                    if columns is not None and getattr(columns, key) is not None})
        return out


class Scene(_Section):
    """A scene: its kind, where its data come from, and the skin it is on."""

    kind: Literal[KIND_NAMES]  # type: ignore[valid-type]
    # simulated (the Python board) | emulated (the firmware under simavr: make firmware)
    # | serial (a board) | import
    source: Source
    # The skin the scene is on: {rows, columns} or {channels, grid | x_mm + y_mm}; none is
    # the paper's 10 × 10 (eskin.skin).
    skin: SkinSpec | None = None


class AcquiredScene(Scene):
    """A simulated, emulated or serial scene: a plan of conditions, recorded."""

    port: str | None = None      # serial: /dev/ttyACM0, socket://127.0.0.1:5000, ...
    stretches: Annotated[list[_real(ge=1)], Field(min_length=1)]
    forces: Annotated[list[NonNegative], Field(min_length=1)]
    samples: Count
    # Trials per condition: the whole plan recorded this many times, each time a new trial
    # (weights placed anew). 1 is the paper's protocol.
    repeats: Count = 1
    nodes_x: list[Annotated[int, Field(ge=1)]] | None = None
    nodes_y: list[Annotated[int, Field(ge=1)]] | None = None

    @model_validator(mode="after")
    def _source_fields(self) -> AcquiredScene:
        if self.source == "serial" and not self.port:
            raise ValueError("source is 'serial' but port is unset")
        return self

    @model_validator(mode="after")
    def _kind_fields(self) -> AcquiredScene:
        kind = KINDS[self.kind]
        two = kind.contacts > 1
        skin = scene_skin(self)
        for name, top in (("nodes_x", skin.size_x), ("nodes_y", skin.size_y)):
            if two and not getattr(self, name):
                raise ValueError(f"a {kind.name} scene needs {name} (a list of nodes 1..{top})")
            if not two and getattr(self, name) is not None:
                raise ValueError(f"{name} belongs to scenes of two contacts only")
            beyond = [n for n in getattr(self, name) or [] if n > top]
            if beyond:
                raise ValueError(f"{name} {beyond} lie off the skin, whose nodes are 1..{top} "
                                 f"along {name[-1]} ({skin.describe()}; set skin: to declare "
                                 "another)")
        if two and any(force <= 0 for force in self.forces):
            raise ValueError("two-force levels must be > 0 (both indenters touch)")
        return self


class ImportedScene(Scene):
    """A scene read from files (``source: import``): no plan; labels from the files."""

    model_config = ConfigDict(serialize_by_alias=True)
    import_: Import = Field(alias="import")

    @model_validator(mode="before")
    @classmethod
    def _no_plan(cls, data: Any) -> Any:
        plan = [key for key in PLAN_KEYS if isinstance(data, Mapping) and key in data]
        if plan:
            then = "" if "import" in data else "; set import.path to the files"
            raise ValueError(f"an import scene's labels come from its files, not a plan: "
                             f"remove {', '.join(plan)}{then}")
        return data

    @model_validator(mode="after")
    def _labels(self) -> ImportedScene:
        """The column map gives every label of the scene's kind, on its skin."""
        spec, kind, skin = self.import_, KINDS[self.kind], scene_skin(self)
        columns = spec.columns
        if columns is None:
            return self
        if isinstance(columns.channels, list) and len(columns.channels) != skin.terminals:
            raise ValueError(f"import.columns.channels lists {len(columns.channels)} columns "
                             f"but the skin has {skin.terminals} channels ({skin.describe()})")
        others = [key for key in (*FORCE_KEYS, *POSITION_KEYS)
                  if getattr(columns, key) is not None
                  and key.removesuffix("_mm") not in (*kind.force_columns, *kind.node_columns)
                  and not (key == "force" and kind.contacts > 1)]
        if others:
            raise ValueError(f"import.columns.{others[0]} is not a label of a {kind.name} "
                             f"scene ({', '.join(kind.labels)})")
        given = [force for force in kind.force_columns if getattr(columns, force) is not None]
        total = import_kind(self.kind, spec).total_force
        if total and given:
            raise ValueError(f"import.columns: force (the total) and {', '.join(given)} (per "
                             "contact) both given; keep one")
        if not total and len(given) != len(kind.force_columns):
            need = "force" if kind.contacts == 1 else \
                f"{' and '.join(kind.force_columns)}, or force (their total)"
            raise ValueError(f"import.columns needs {need}: the column of the force (N)")
        sources = spec.position_sources()
        for node in kind.node_columns:
            found = [key for key in (node, f"{node}_mm") if key in sources]
            if len(found) != 1:
                ways = (f"import.columns.{node} (a node) or .{node}_mm (mm), or a group "
                        f"{node} or {node}_mm of import.position_from_name")
                raise ValueError(f"{' and '.join(found)} both give {node}; keep one" if found
                                 else f"no column gives {node}: set {ways}")
            if found[0].endswith("_mm") and getattr(skin, f"{node[0]}_mm") is None:
                raise ValueError(f"{node} is given in mm but the skin places no grid line in "
                                 f"mm: set skin.{node[0]}_mm ({skin.describe()})")
        if spec.position_tolerance_mm is not None and not any(k.endswith("_mm")
                                                              for k in sources):
            raise ValueError("position_tolerance_mm applies to positions in mm; none is given")
        return self


def _scene_source(value: Any) -> str:
    source = value.get("source") if isinstance(value, Mapping) else getattr(value, "source", None)
    return "imported" if source == "import" else "acquired"


# A scene's tag (acquired | imported) is pydantic's, not a key: never one of the keys.
SCENE_SOURCES = ("acquired", "imported")
SceneSpec = Annotated[
    Annotated[AcquiredScene, Tag("acquired")] | Annotated[ImportedScene, Tag("imported")],
    Discriminator(_scene_source)]


def scene_skin(scene: Scene) -> AnySkin:
    """The skin scene ``scene`` is on (eskin.skin): its ``skin`` section, or the paper's."""
    spec = scene.skin
    if spec is None:
        return PAPER_SKIN
    return skin_from_dict(untraced(spec).model_dump(exclude_none=True))


def import_kind(kind: str, spec: Import | None) -> Kind:
    """The kind of the labels an import of a ``kind`` scene makes (eskin.kinds): the
    kind's own, or, where its column map gives several contacts' total force only
    (``import.columns.force``), the kind's total-force variant."""
    declared = KINDS[kind]
    columns = spec.columns if spec is not None else None
    if declared.contacts > 1 and columns is not None and columns.force is not None:
        return declared.with_total_force()
    return declared


def scene_kind(scene: Scene) -> Kind:
    """The kind of scene ``scene``'s dataset: its ``kind``, or that kind's total-force
    variant where its import gives only the total (:func:`import_kind`)."""
    return import_kind(scene.kind, scene.import_ if isinstance(scene, ImportedScene) else None)


class Ingest(_Section):
    bad_rows: Literal["error", "quarantine"]


class Featurize(_Section):
    method: Literal["raw", "standardise", "baseline"]


class CV(_Section):
    schemes: Annotated[list[Scheme], Field(min_length=1)]
    folds: Annotated[int, Field(ge=2)]
    seed: Seed
    n_jobs: Jobs
    backend: Backend


class TaskModels(BaseModel):
    """``model: <name>`` (or a name per kind of scene) and, beside it, candidates'
    hyperparameters by name (a model with no entry takes its defaults:
    ``-S train.<task>.model=<name>``). The name itself is checked against the registry
    by the train step, which imports it."""

    model_config = ConfigDict(extra="allow", strict=True)
    model: str | dict[Literal[KIND_NAMES], str]  # type: ignore[valid-type]
    __pydantic_extra__: dict[str, dict[str, Any]]


# train: ``configuration``, then one TaskModels per task, shared by every scene (the
# stage of scene s and task t reads train.configuration and train.<t>).
Train = create_model(
    "Train", __base__=_Section, configuration=(Literal["tuned", "paper"], ...),
    **{name: (TaskModels, ...) for name in TASK_NAMES})


class Report(_Section):
    schemes: Annotated[list[Scheme], Field(min_length=1)]
    plots_scheme: Scheme
    dpi: Count
    page_dpi: Count


class Variant(BaseModel):
    model_config = ConfigDict(extra="allow", strict=True)
    model: str


class Bench(_Section):
    schemes: Annotated[list[Scheme], Field(min_length=1)]
    evaluate_folds: Count
    scaling_fractions: list[Positive]
    seed: Seed
    n_jobs: Jobs
    backend: Backend
    import_rows: list[Count] = []
    repro_baseline: str = ""  # the revision make bench's repro_speed times against
    tasks: dict[str, dict[str, Variant]]


class NoiseScene(_Section):
    stretches: Annotated[list[_real(ge=1)], Field(min_length=1)]
    forces: Annotated[list[NonNegative], Field(min_length=1)]
    samples: Count


class Stress(_Section):
    trials: Count
    folds: Annotated[int, Field(ge=2)]
    seed: Seed
    noise_scene: NoiseScene
    large_gp_rows: Annotated[int, Field(ge=0)]


class LiveBaseline(_Section):
    """How `eskin live` follows a board's offset from the training's untouched readings
    after the tare (eskin/deploy/live.py)."""

    time_constant_s: NonNegative = 0.5   # 0: the tare's offset, never followed
    gate_counts: Positive = 8.0          # a frame updates it only if no channel moved more
    # in contact: freeze it, or follow the channels the contact leaves within the gate
    in_contact: Literal["freeze", "quiet_channels"] = "freeze"
    reach_terminals: Annotated[int, Field(ge=0)] = 2  # quiet_channels: frozen each side of it


class LiveContact(_Section):
    """Contact with hysteresis, on the stack's contact probability (eskin/deploy/live.py)."""

    enter_probability: _real(gt=0, le=1) = 0.8
    leave_probability: _real(ge=0, lt=1) = 0.5
    min_duration_ms: NonNegative = 50.0

    @model_validator(mode="after")
    def _ordered(self) -> LiveContact:
        if self.leave_probability > self.enter_probability:
            raise ValueError(f"leave_probability ({self.leave_probability}) is above "
                             f"enter_probability ({self.enter_probability}): contact would "
                             "end before it began")
        return self


class Live(_Section):
    """`eskin live`'s knobs (and make bench's live hour): not read by `dvc repro`. The
    defaults are params.yaml's, for the library's callers that pass none."""

    tare_frames: Annotated[int, Field(ge=0)] = 100
    baseline: LiveBaseline = LiveBaseline()
    contact: LiveContact = LiveContact()


class Params(_Section):
    """params.yaml: the pipeline's knobs, every one read by a stage of dvc.yaml (`dvc exp
    show` lists the whole file)."""

    sim: Sim
    sim_board: SimBoard
    acquire: Acquire
    scenes: Annotated[dict[Annotated[str, Field(pattern=SCENE_NAME)], SceneSpec],
                      Field(min_length=1)]
    ingest: Ingest
    featurize: Featurize
    cv: CV
    train: Train  # type: ignore[valid-type]
    report: Report
    live: Live


class LiveHour(_Section):
    """make bench's live hour (harness/live_hour.py): the script of the hour."""

    seed: Seed
    minutes: Positive
    untouched_s: Positive        # between two events of the script
    presses: Annotated[int, Field(ge=0)]
    press_s: Positive
    sustained_s: Positive
    stretches_mm: list[NonNegative]
    retare_after_sustained: bool
    press_ramp_ms: NonNegative
    batch_frames: Count


class LearningCurve(_Section):
    """make bench's learning curves (harness/learning_curve.py) and `eskin plan`'s costs."""

    repeats: Annotated[list[Count], Field(min_length=1)]  # trials per condition trained on
    placement_s: NonNegative    # an operator's time to place one trial's weights
    frames_per_s: Positive      # the board's frame rate (the firmware's, measured)
    gap_share: Annotated[float, Field(gt=0, lt=1)] = 0.8  # of the paper→bound gap, to close
    gap_tasks: list[TaskName] = []   # the tasks whose recommended repeats are checked

    @field_validator("repeats")
    @classmethod
    def _increasing(cls, value: list[int]) -> list[int]:
        if value != sorted(set(value)):
            raise ValueError(f"must be increasing, without repeats: {value}")
        return value


class BenchParams(_Section):
    """bench/params.yaml: `make bench`'s knobs (bench/dvc.yaml)."""

    bench: Bench
    soak: Soak
    fuzz: Fuzz
    live_hour: LiveHour
    learning_curve: LearningCurve


class StressParams(_Section):
    """stress/params.yaml: `make stress`'s knobs (stress/dvc.yaml)."""

    stress: Stress


Schema = typing.TypeVar("Schema", bound=_Section)
# Which file each section lives in (a section written in another file is told where to go).
SECTION_FILES = {name: path for path, schema in ((DEFAULT_PARAMS, Params),
                                                 (BENCH_PARAMS, BenchParams),
                                                 (STRESS_PARAMS, StressParams))
                 for name in schema.model_fields}


# The sections `dvc repro` reads, which are params.yaml's (make bench's and make stress's
# have files of their own): the tracking stage logs these to the pipeline's MLflow run.
# `live` is `eskin live`'s (and the bench's live hour's): no pipeline stage reads it.
PIPELINE_SECTIONS: tuple[str, ...] = tuple(name for name in Params.model_fields
                                           if name != "live")


def pipeline_params(params: Params) -> dict[str, Any]:
    """The sections the pipeline reads (:data:`PIPELINE_SECTIONS`), as written: keys the
    file leaves out stay out."""
    out: dict[str, Any] = {}
    for name in PIPELINE_SECTIONS:
        section = getattr(params, name)
        out[name] = ({key: spec.model_dump(exclude_unset=True) for key, spec in section.items()}
                     if isinstance(section, Mapping) else section.model_dump(exclude_unset=True))
    return out


def _describe(error: dict) -> str:
    """One pydantic error as ``key = value: what is allowed``."""
    loc = [str(part) for part in error["loc"]]
    if loc[-1:] == ["[key]"]:  # a mapping's key: only scene names are checked
        return (f"{'.'.join(loc[:-2])}: {loc[-2]!r} is not a valid scene name (letters, "
                "digits and _, starting with a letter: it names DVC stages and directories)")
    key = ".".join(loc)
    message = error["msg"].removeprefix("Value error, ")
    if error["type"] == "missing":
        return f"{key} is missing (required)"
    if error["type"] == "extra_forbidden":
        return f"{key} is not a known key"
    value = error.get("input")
    if isinstance(value, Mapping):  # a rule on a whole section: its message says what
        return f"{key}: {message}"
    return f"{key} = {value!r}: {message}" if key else message


def _is_model(model: Any) -> bool:
    return isinstance(model, type) and issubclass(model, BaseModel)


def _keys(model: type[BaseModel]) -> dict[str, Any]:
    """A section's fields by the key the file writes (``import`` for ``import_``)."""
    return {field.alias or name: field for name, field in model.model_fields.items()}


def _section_models(loc: tuple, schema: type[BaseModel]) -> list[type[BaseModel]]:
    """The section of ``schema`` (pydantic models: several where a section takes one of a
    few forms, as a scene does) at ``loc`` (``("cv",)``, ``("scenes", "a")``), or none where
    the params there are free-form (hyperparameters)."""
    models: Any = [schema]
    for part in loc:
        if isinstance(models, tuple):  # a mapping: any key, then its values' models
            models = models[1]
            continue
        found = [_keys(m)[part] for m in models if _is_model(m) and part in _keys(m)]
        if not found:
            return []
        models = _unwrap(found[0].annotation)
    return [m for m in models if _is_model(m)] if isinstance(models, list) else []


def _unwrap(annotation: Any) -> Any:
    """A field's models, through Optional, Annotated and unions (a list); a dict as (None,
    its values')."""
    origin = typing.get_origin(annotation)
    if origin is Annotated:
        return _unwrap(typing.get_args(annotation)[0])
    if origin in (typing.Union, types.UnionType):
        unwrapped = [_unwrap(a) for a in typing.get_args(annotation) if a is not type(None)]
        return [m for options in unwrapped if isinstance(options, list) for m in options]
    if origin is dict:
        return (None, _unwrap(typing.get_args(annotation)[1]))
    return [annotation]


def _known_keys(loc: tuple, schema: type[BaseModel]) -> list[str]:
    return list(dict.fromkeys(key for model in _section_models(loc, schema)
                              for key in _keys(model)))


def _typo_errors(errors: list[dict], schema: type[BaseModel]) -> list[str]:
    """Unknown keys, each with the key of its section it most resembles (``cv.fols is
    not a known key; did you mean cv.folds?``) and, where that key is missing, saying so
    in the same message. Returns the messages; the unknown keys, and the missing keys
    they stand for, are taken out of ``errors``."""
    missing = {tuple(e["loc"]): e for e in errors if e["type"] == "missing"}
    messages = []
    for error in [e for e in errors if e["type"] == "extra_forbidden"]:
        loc = tuple(error["loc"])
        section, key = loc[:-1], str(loc[-1])
        if not section and key in SECTION_FILES:  # another params file's section
            errors.remove(error)
            messages.append(f"{key} is not a section of this file: move it to "
                            f"{SECTION_FILES[key]}")
            continue
        dotted = ".".join(str(p) for p in section)
        prefix = f"{dotted}." if dotted else ""
        absent = [str(m[-1]) for m in missing if m[:-1] == section]
        close = (difflib.get_close_matches(key, absent, n=1, cutoff=0.6)
                 or difflib.get_close_matches(key, _known_keys(section, schema), n=1,
                                              cutoff=0.6))
        if close:
            text = f"{prefix}{key} is not a known key; did you mean {prefix}{close[0]}?"
            if close[0] in absent:
                errors.remove(missing.pop((*section, close[0])))
                text += f" ({prefix}{close[0]} is missing)"
        else:
            known = _known_keys(section, schema)
            text = f"{prefix}{key} is not a known key" + (
                f" of {dotted or 'the params file'} (known: {', '.join(known)})" if known else "")
        errors.remove(error)
        messages.append(text)
    return messages


def validate_params(params: Any, path: Path = DEFAULT_PARAMS,
                    schema: type[Schema] = Params) -> Schema:
    """``params`` (a mapping, as YAML gives it) checked against ``schema`` (:class:`Params`,
    :class:`BenchParams`, :class:`StressParams`): the typed model, or ParamsError naming
    the first mistake. An unknown key comes first, with the known key it most resembles:
    a typo shows up as both an unknown key and a missing one, and the unknown one is the
    mistake to name."""
    if not isinstance(params, dict):
        raise ParamsError(f"{path}: expected a mapping of sections, got "
                          f"{type(params).__name__}")
    try:
        return schema.model_validate(params)
    except ValidationError as err:
        # A skin's layout tag (row_column | channel_array) and a scene's (acquired |
        # imported) are pydantic's, not keys.
        errors = [{**e, "loc": tuple(p for p in e["loc"]
                                     if p not in SKIN_LAYOUTS + SCENE_SOURCES)}
                  for e in err.errors()]
        messages = _typo_errors(errors, schema) + [_describe(e) for e in errors]
        more = f" (and {len(messages) - 1} more)" if len(messages) > 1 else ""
        raise ParamsError(f"{path}: {messages[0]}{more}") from None


def load_params(path: Path = DEFAULT_PARAMS, schema: type[Schema] = Params) -> Schema:
    """The params file at ``path``, validated against ``schema`` (``load_params()``: the
    pipeline's; ``load_params(BENCH_PARAMS, BenchParams)``: `make bench`'s), with
    ``ESKIN_PARAMS_TRACE`` set, a proxy of it that notes the keys read."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no params file (run from the project root)")
    if path.is_dir():
        raise ParamsError(f"{path}: is a directory, not a params file")
    try:
        with path.open(encoding="utf-8") as handle:
            params = yaml.safe_load(handle)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f"{path}:{mark.line + 1}:{mark.column + 1}" if mark else str(path)
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise ParamsError(f"{where}: not valid YAML: {problem}") from None
    except UnicodeDecodeError as err:
        raise ParamsError(f"{path}: not UTF-8 text ({err.reason})") from None
    params = validate_params(params, path, schema)
    trace_dir = os.environ.get(TRACE_ENV)
    return _traced(params, path, trace_dir) if trace_dir else params


def get_scene(params: Params, name: str, path: Path | str = DEFAULT_PARAMS) -> Scene:
    """The scene called ``name`` in the params file; else one line naming the scenes it
    has (and the closest, for a typo). Every command and stage that takes a scene asks
    here first, so that a wrong name is never advice to run a stage that does not exist."""
    scenes = params.scenes
    if name in scenes:
        return scenes[name]
    with validating():  # listing the names is not reading a stage's knob
        names = list(scenes)
    close = difflib.get_close_matches(name, names, n=1)
    hint = f"; did you mean {close[0]}?" if close else ""
    raise ParamsError(f"{path} has no scene {name!r}{hint} (its scenes: {', '.join(names)})")


# ------------------------------------------------------------------ read tracing
#
# With ESKIN_PARAMS_TRACE set, load_params returns a proxy over the model: a leaf value
# read (an attribute or an item that is not a section: a number, a string, a list)
# notes its dotted key; a section read whole (iterated, model_dump, model_extra,
# model_copy, items(), values()) notes the section's key; a section reached on the way
# (params.scenes[name]) notes nothing by itself.

class _Traced:
    """A params model (or one of its sections) that notes the keys read from it."""

    __slots__ = ("_target", "_key", "_reads")

    def __init__(self, target: Any, key: str, reads: set[str]) -> None:
        object.__setattr__(self, "_target", target)
        object.__setattr__(self, "_key", key)
        object.__setattr__(self, "_reads", reads)

    def _child(self, name: Any, value: Any) -> Any:
        key = f"{self._key}.{name}" if self._key else str(name)
        if isinstance(value, BaseModel):
            return _TracedModel(value, key, self._reads)
        if isinstance(value, Mapping):
            return _TracedMapping(value, key, self._reads)
        if _recording[0]:
            self._reads.add(key)
        return value

    def _whole(self) -> None:
        if _recording[0]:
            self._reads.add(self._key or "*")

    def __repr__(self) -> str:
        return f"traced({self._target!r})"


_WHOLE_METHODS = {"model_dump", "model_dump_json", "model_copy"}


class _TracedModel(_Traced):
    """A pydantic section: fields (and extras) are read as attributes."""

    def __getattr__(self, name: str) -> Any:
        target = self._target
        fields = type(target).model_fields
        if name in fields or name in (target.model_extra or {}):
            key = fields[name].alias or name if name in fields else name  # as the file has it
            return self._child(key, getattr(target, name))
        if name == "model_extra":
            self._whole()
            return target.model_extra
        if name in _WHOLE_METHODS:
            self._whole()
        return getattr(target, name)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"params are read-only ({self._key or 'params'}.{name})")

    def __eq__(self, other: object) -> bool:
        self._whole()
        return self._target == untraced(other)

    __hash__ = None  # type: ignore[assignment]


class _TracedMapping(_Traced, Mapping):
    """A mapping in the params (scenes, a task's model per kind, hyperparameters)."""

    def __getitem__(self, name: Any) -> Any:
        return self._child(name, self._target[name])

    def __contains__(self, name: object) -> bool:  # asking is not reading a knob
        return name in self._target

    def __len__(self) -> int:
        return len(self._target)

    def __iter__(self):
        self._whole()
        return iter(self._target)

    def __eq__(self, other: object) -> bool:
        self._whole()
        return self._target == untraced(other)

    __hash__ = None  # type: ignore[assignment]


def untraced(params: Any) -> Any:
    """The model (or mapping) under a traced proxy, ``params`` itself otherwise: for
    bookkeeping that is not a stage's knob (the whole file logged to MLflow)."""
    return object.__getattribute__(params, "_target") if isinstance(params, _Traced) else params


_recording = [True]


@contextlib.contextmanager
def validating():
    """Reads that only check the file (another scene's import path exists, before a long
    acquisition) are not a stage's knobs: not traced."""
    was, _recording[0] = _recording[0], False
    try:
        yield
    finally:
        _recording[0] = was


def _traced(params: Schema, path: Path, trace_dir: str) -> Schema:
    reads: set[str] = set()
    # one file per params file loaded (a bench stage loads two)
    out = Path(trace_dir) / f"params-read-{os.getpid()}-{str(path).replace(os.sep, '_')}.json"

    def write() -> None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps({"argv": sys.argv, "file": str(path),
                                   "reads": sorted(reads)}))

    atexit.register(write)
    return _TracedModel(params, "", reads)  # type: ignore[return-value]
