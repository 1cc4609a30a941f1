"""params.yaml, bench/params.yaml and stress/params.yaml: the one place every knob lives,
checked at load, read as typed sections. This module is the loader and the section's base;
each section's schema is a module of its own (eskin.config.<section>), so that a stage
imports, and so depends on, only the sections it reads.

:func:`load_params` validates a file (or the sections of it a stage reads) against its
schema (pydantic, strict: types, ranges, required keys, no unknown keys) before any
step runs, so a typo or a wrong type is one line naming the file, the key, the value
and what is allowed: never a traceback after an hour of acquisition, and
never a value silently truncated or replaced by a default.
"""

from __future__ import annotations

import atexit
import contextlib
import difflib
import json
import os
import sys
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, WrapValidator, create_model

from eskin.catalog import SCHEMES, TASK_NAMES
from eskin.errors import EskinError

DEFAULT_PARAMS = Path("params.yaml")
# The subprojects' own default params files (bench/dvc.yaml, stress/dvc.yaml), from the
# project root, where their stages run.
BENCH_PARAMS = Path("bench/params.yaml")
STRESS_PARAMS = Path("stress/params.yaml")
# Set to a directory, each process notes there the params keys it read after validation
# (tests/test_stage_deps.py compares them with each DVC stage's declared params).
TRACE_ENV = "ESKIN_PARAMS_TRACE"

# Every section of every params file, by the file it belongs in (a section written in
# another file is told where to go; one a file lacks is a typo). Named here, not gathered
# from the schemas, so that loading one section imports no other's schema (a test checks
# that the full schemas name the same).
SECTION_FILES: dict[str, Path] = {
    **dict.fromkeys(("sim", "sim_board", "acquire", "scenes", "ingest", "featurize", "cv",
                     "train", "report", "live"), DEFAULT_PARAMS),
    **dict.fromkeys(("bench", "soak", "fuzz", "live_hour", "hard_hour",
                     "learning_curve"), BENCH_PARAMS),
    "stress": STRESS_PARAMS,
}


# A scene name becomes a DVC stage name (acquire@<scene>, train@<scene>), a
# directory and an MLflow tag: letters, digits and underscores, starting with a letter.
SCENE_NAME = r"^[A-Za-z][A-Za-z0-9_]*$"


class ParamsError(EskinError, ValueError):
    """params.yaml cannot be used as written; the message names the key."""


class Section(BaseModel):
    """A section of a params file, or a schema of several (``file``: whose)."""

    # strict: "ten" is not 10, 2.5 is not 2, 1.0 is not [1.0]; finite numbers only.
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)
    file: ClassVar[Path] = DEFAULT_PARAMS
    # a schema of some of the file's sections: the others are checked by name only
    partial: ClassVar[bool] = False


def _as_written(value: Any, handler: Any) -> Any:
    """A number checked as a float but kept as written: ``40`` stays the int 40, so the
    values the library reads (and MLflow logs) are the file's, as before the model."""
    checked = handler(value)
    return value if type(value) is int else checked


def real(**constraints: Any) -> Any:
    """A float field (strict: no strings, no bools) that keeps an int as written."""
    return Annotated[float, Field(**constraints), WrapValidator(_as_written)]


Real = real()
Probability = real(ge=0, lt=1)
Positive = real(gt=0)
NonNegative = real(ge=0)
Count = Annotated[int, Field(ge=1)]
Seed = Annotated[int, Field(ge=0)]
Scheme = Literal[SCHEMES]  # type: ignore[valid-type]
TaskName = Literal[TASK_NAMES]  # type: ignore[valid-type]
Backend = Literal["loky", "threading", "sequential", "dask"]
Jobs = Annotated[int, Field(ge=-1)]

Schema = typing.TypeVar("Schema", bound=Section)


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
    if not loc and getattr(schema, "partial", False):  # every section of the file
        return [name for name, file in SECTION_FILES.items() if file == schema.file]
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


def sections(file: Path = DEFAULT_PARAMS, **fields: Any) -> type[Section]:
    """A schema of some of ``file``'s sections, by name (``sections(cv=CV)``): what a stage
    reads. The sections it leaves out are checked by name only, so that the stage imports
    (and, in dvc.yaml, depends on) only the schemas of what it reads; each section is
    checked whole by every stage that reads it."""
    model = create_model("Sections", __base__=Section,
                         **{name: (annotation, ...) for name, annotation in fields.items()})
    model.file, model.partial = file, True
    return model


# A skin's layout tag (row_column | channel_array) and a scene's (acquired | imported)
# are pydantic's, not keys: never in a key's name.
SKIN_LAYOUTS = ("row_column", "channel_array")
SCENE_SOURCES = ("acquired", "imported")


def _other_sections(params: dict, schema: type[Section]) -> tuple[dict, list[dict]]:
    """A partial schema's own sections of ``params``, and an error for each top-level key
    that is no section of the schema's file (as pydantic words an unknown key)."""
    own = {name: value for name, value in params.items() if name in schema.model_fields}
    unknown = [{"type": "extra_forbidden", "loc": (name,), "msg": "", "input": params[name]}
               for name in params
               if name not in schema.model_fields and SECTION_FILES.get(name) != schema.file]
    return own, unknown


def validate_params(params: Any, schema: type[Schema], path: Path | None = None) -> Schema:
    """``params`` (a mapping, as YAML gives it) checked against ``schema`` (a file's,
    as eskin.config.params.Params, or some of its :func:`sections`): the typed model, or
    ParamsError naming the first mistake. An unknown key comes first, with the known key it
    most resembles: a typo shows up as both an unknown key and a missing one, and the
    unknown one is the mistake to name."""
    path = schema.file if path is None else path
    if not isinstance(params, dict):
        raise ParamsError(f"{path}: expected a mapping of sections, got "
                          f"{type(params).__name__}")
    errors: list[dict] = []
    if schema.partial:
        params, errors = _other_sections(params, schema)
    try:
        model = schema.model_validate(params)
    except ValidationError as err:
        errors += [{**e, "loc": tuple(p for p in e["loc"] if p not in SKIN_LAYOUTS + SCENE_SOURCES)}
                   for e in err.errors()]
    if not errors:
        return model
    messages = _typo_errors(errors, schema) + [_describe(e) for e in errors]
    more = f" (and {len(messages) - 1} more)" if len(messages) > 1 else ""
    raise ParamsError(f"{path}: {messages[0]}{more}")


def load_params(schema: type[Schema], path: Path | str | None = None) -> Schema:
    """The params file at ``path`` (default: the schema's own file) validated against
    ``schema`` (``load_params(Params)``: the whole of params.yaml; ``load_params(
    sections(cv=CV))``: its cv section), with ``ESKIN_PARAMS_TRACE`` set, a proxy of it
    that notes the keys read."""
    path = Path(schema.file if path is None else path)
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
    params = validate_params(params, schema, path)
    trace_dir = os.environ.get(TRACE_ENV)
    return _traced(params, path, trace_dir) if trace_dir else params


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


_TRACED_READS: dict[Path, set[str]] = {}  # by trace file: every load of it in this process


def _traced(params: Schema, path: Path, trace_dir: str) -> Schema:
    # one file per params file loaded (a bench stage loads two), holding what every load
    # of it in this process read (a stage that runs several steps loads it once a step)
    out = Path(trace_dir) / f"params-read-{os.getpid()}-{str(path).replace(os.sep, '_')}.json"
    if out not in _TRACED_READS:
        reads = _TRACED_READS[out] = set()

        def write() -> None:
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_text(json.dumps({"argv": sys.argv, "file": str(path),
                                       "reads": sorted(reads)}))

        atexit.register(write)
    return _TracedModel(params, "", _TRACED_READS[out])  # type: ignore[return-value]
