"""params.yaml: the one place every knob lives, checked once at load, read by section.

:func:`load_params` validates the whole file against a declared schema
(pydantic, strict: types, ranges, required keys, no unknown keys) before any
step runs, so a typo or a wrong type is one line naming the key, the value
and what is allowed — never a traceback after an hour of acquisition, and
never a value silently truncated or replaced by a default.
"""

from __future__ import annotations

import atexit
import contextlib
import json
import os
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, create_model, model_validator

from eskin.catalog import SCHEMES, SOURCES, TASK_NAMES
from eskin.errors import EskinError
from eskin.kinds import KIND_NAMES, KINDS
from eskin.skin import PAPER_SKIN

DEFAULT_PARAMS = Path("params.yaml")
# Set to a directory, each process notes there the params keys it read after validation
# (tests/test_stage_deps.py compares them with each DVC stage's declared params).
TRACE_ENV = "ESKIN_PARAMS_TRACE"


class ParamsError(EskinError, ValueError):
    """params.yaml cannot be used as written; the message names the key."""


# ------------------------------------------------------------------ schema

class _Section(BaseModel):
    # strict: "ten" is not 10, 2.5 is not 2, 1.0 is not [1.0]; finite numbers only.
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)


Probability = Annotated[float, Field(ge=0, lt=1)]
Positive = Annotated[float, Field(gt=0)]
NonNegative = Annotated[float, Field(ge=0)]
Count = Annotated[int, Field(ge=1)]
Seed = Annotated[int, Field(ge=0)]
Scheme = Literal[SCHEMES]  # type: ignore[valid-type]
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
    strain_max: Annotated[float, Field(gt=0, lt=1)]
    force_half_n: Positive
    force_hill: Positive
    stretch_stiffening: float
    reach_nodes: Annotated[int, Field(ge=0)]
    placement_sd_nodes: NonNegative
    # below half a pitch, so that an indenter stays on its node
    placement_max_nodes: Annotated[float, Field(lt=0.5)]
    node_sensitivity_spread: NonNegative
    seating_force_n: NonNegative
    seating_variation: NonNegative
    noise_pf: NonNegative
    drift_offset_pf: NonNegative
    drift_step_pf: NonNegative
    cav424_ref_pf: Positive
    cav424_gain_v: Positive
    cav424_gain_spread: NonNegative
    cav424_offset_v: float
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


class Soak(_Section):
    corrupt_fraction: Probability
    faults: Faults
    timeout_s: Positive
    max_attempts: Count
    reconnect_s: NonNegative
    kill_at: list[Annotated[float, Field(gt=0, lt=1)]]


class Fuzz(_Section):
    examples: Count


Source = Literal[SOURCES]  # type: ignore[valid-type]
# A scene name becomes a DVC stage name (acquire@<scene>, train@<scene>-<task>), a
# directory and an MLflow tag: letters, digits and underscores, starting with a letter.
SCENE_NAME = r"^[A-Za-z][A-Za-z0-9_]*$"


class Scene(_Section):
    kind: Literal[KIND_NAMES]  # type: ignore[valid-type]
    # simulated (the Python board) | emulated (the firmware under simavr: make firmware)
    # | serial (a board) | import
    source: Source
    port: str | None = None      # serial: /dev/ttyACM0, socket://127.0.0.1:5000, ...
    import_path: str | None = None  # import: a CSV or Parquet file in the paper's layout
    stretches: Annotated[list[Annotated[float, Field(ge=1)]], Field(min_length=1)]
    forces: Annotated[list[NonNegative], Field(min_length=1)]
    samples: Count
    nodes_x: list[Annotated[int, Field(ge=1, le=PAPER_SKIN.rows)]] | None = None
    nodes_y: list[Annotated[int, Field(ge=1, le=PAPER_SKIN.columns)]] | None = None

    @model_validator(mode="after")
    def _source_fields(self) -> Scene:
        if self.source == "import" and not self.import_path:
            raise ValueError("source is 'import' but import_path is unset")
        if self.source == "serial" and not self.port:
            raise ValueError("source is 'serial' but port is unset")
        return self

    @model_validator(mode="after")
    def _kind_fields(self) -> Scene:
        kind = KINDS[self.kind]
        two = kind.contacts > 1
        for name, top in (("nodes_x", PAPER_SKIN.rows), ("nodes_y", PAPER_SKIN.columns)):
            if two and not getattr(self, name):
                raise ValueError(f"a {kind.name} scene needs {name} (a list of nodes 1..{top})")
            if not two and getattr(self, name) is not None:
                raise ValueError(f"{name} belongs to scenes of two contacts only")
        if two and any(force <= 0 for force in self.forces):
            raise ValueError("two-force levels must be > 0 (both indenters touch)")
        return self


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
    stretches: Annotated[list[Annotated[float, Field(ge=1)]], Field(min_length=1)]
    forces: Annotated[list[NonNegative], Field(min_length=1)]
    samples: Count


class Stress(_Section):
    trials: Count
    folds: Annotated[int, Field(ge=2)]
    seed: Seed
    noise_scene: NoiseScene
    large_gp_rows: Annotated[int, Field(ge=0)]


class Params(_Section):
    sim: Sim
    sim_board: SimBoard
    acquire: Acquire
    scenes: Annotated[dict[Annotated[str, Field(pattern=SCENE_NAME)], Scene],
                      Field(min_length=1)]
    ingest: Ingest
    featurize: Featurize
    cv: CV
    train: Train  # type: ignore[valid-type]
    report: Report
    # make bench / make stress only: a lab's params file may leave them out.
    soak: Soak | None = None
    fuzz: Fuzz | None = None
    bench: Bench | None = None
    stress: Stress | None = None


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
        return f"{key}: unknown key (a typo?)"
    value = error.get("input")
    if isinstance(value, Mapping):  # a rule on a whole section: its message says what
        return f"{key}: {message}"
    return f"{key} = {value!r}: {message}" if key else message


def validate_params(params: Any, path: Path = DEFAULT_PARAMS) -> dict[str, Any]:
    """``params`` checked against the schema; ParamsError naming the first mistake."""
    if not isinstance(params, dict):
        raise ParamsError(f"{path}: expected a mapping of sections, got "
                          f"{type(params).__name__}")
    try:
        Params.model_validate(params)
    except ValidationError as err:
        errors = err.errors()
        more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
        raise ParamsError(f"{path}: {_describe(errors[0])}{more}") from None
    return params


def load_params(path: Path = DEFAULT_PARAMS) -> dict[str, Any]:
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
    params = validate_params(params, path)
    trace_dir = os.environ.get(TRACE_ENV)
    return _traced(params, trace_dir) if trace_dir else params


# ------------------------------------------------------------------ read tracing

class _TracedSection(dict):
    """A params mapping that notes the keys read from it: a value's dotted key when a
    value is read, a section's when the section is read whole (iterated, copied)."""

    def __init__(self, data: Mapping[str, Any], key: str, reads: set[str]) -> None:
        # Sections wrapped once, here, so a section read twice is one object (and a
        # change made through one reference is seen through the other).
        super().__init__({name: _TracedSection(value, self._join(key, name), reads)
                          if isinstance(value, dict) else value
                          for name, value in data.items()})
        self._key, self._reads = key, reads

    @staticmethod
    def _join(key: str, name: str) -> str:
        return f"{key}.{name}" if key else str(name)

    def _child(self, name: str, value: Any) -> Any:
        if not isinstance(value, _TracedSection) and _recording[0]:
            self._reads.add(self._join(self._key, name))
        return value

    def _whole(self) -> None:
        if _recording[0]:
            self._reads.add(self._key or "*")

    def __getitem__(self, name: str) -> Any:
        return self._child(name, super().__getitem__(name))

    def get(self, name: str, default: Any = None) -> Any:
        return self[name] if name in self else default

    def __iter__(self):
        self._whole()
        return super().__iter__()

    def keys(self):
        self._whole()
        return super().keys()

    def items(self):
        self._whole()
        return super().items()

    def values(self):
        self._whole()
        return super().values()

    def __deepcopy__(self, memo: dict) -> dict:
        import copy

        self._whole()
        return copy.deepcopy(dict(super().items()), memo)


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


def _traced(params: dict[str, Any], trace_dir: str) -> dict[str, Any]:
    reads: set[str] = set()
    out = Path(trace_dir) / f"params-read-{os.getpid()}.json"

    def write() -> None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps({"argv": sys.argv, "reads": sorted(reads)}))

    atexit.register(write)
    return _TracedSection(params, "", reads)


def section(params: Mapping[str, Any], dotted: str) -> Any:
    """``section(params, "scenes.single_force")``, with an error naming what is missing."""
    node: Any = params
    for i, part in enumerate(dotted.split(".")):
        if not isinstance(node, Mapping) or part not in node:
            where = ".".join(dotted.split(".")[:i + 1])
            raise KeyError(f"params.yaml has no {where}")
        node = node[part]
    return node



