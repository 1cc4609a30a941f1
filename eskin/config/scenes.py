"""params.yaml's ``scenes``: each scene's kind, source (a plan acquired, or files
imported) and skin."""

from __future__ import annotations

import difflib
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import ConfigDict, Discriminator, Field, Tag, create_model, model_validator

from eskin.catalog import SOURCES
from eskin.config.base import (
    DEFAULT_PARAMS,
    SCENE_NAME,
    Count,
    NonNegative,
    ParamsError,
    Positive,
    Real,
    Section,
    real,
    untraced,
    validating,
)
from eskin.kinds import KIND_NAMES, KINDS, Kind
from eskin.skin import PAPER_SKIN, AnySkin, skin_from_dict


class RowColumnSkin(Section):
    """A row/column capacitive skin (eskin.skin.Skin): R × C terminals, R + C channels."""

    rows: Annotated[int, Field(ge=2, le=32)]
    columns: Annotated[int, Field(ge=2, le=32)]


class ChannelArraySkin(Section):
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


SkinSpec = Annotated[
    Annotated[RowColumnSkin, Tag("row_column")] | Annotated[ChannelArraySkin,
                                                            Tag("channel_array")],
    Discriminator(_skin_layout)]


Source = Literal[SOURCES]  # type: ignore[valid-type]
# The plan: what an acquired scene records; an import's labels come from its files.
PLAN_KEYS = ("stretches", "forces", "samples", "repeats", "nodes_x", "nodes_y",
             "contact_counts")

# What an import's columns may give, in the kinds' own words: every kind's forces and
# nodes, each node also as a position in mm (``x_mm``: placed on the skin's grid).
FORCE_KEYS = tuple(dict.fromkeys(c for kind in KINDS.values() for c in kind.force_columns))
NODE_KEYS = tuple(dict.fromkeys(c for kind in KINDS.values() for c in kind.node_columns))
POSITION_KEYS = NODE_KEYS + tuple(f"{node}_mm" for node in NODE_KEYS)
FORCE_UNITS = {"N": 1.0, "mN": 1e-3}
TRIALS = ("labels", "file", "time")

Name = Annotated[str, Field(min_length=1)]
ImportColumns = create_model(
    "ImportColumns", __base__=Section,
    __doc__="Which column of the files gives what (by the header's names): ``channels`` "
            "(a list, matched in order to the skin's channels, or a glob over the header; "
            "default the skin's channel names), the labels, ``time`` (s), ``trial`` and "
            "``rest`` (the sensor's rest force per row, under ``rest.rule: column``).",
    channels=(Name | Annotated[list[Name], Field(min_length=1)] | None, None),
    **{key: (Name | None, None) for key in (*FORCE_KEYS, *POSITION_KEYS, "stretch", "time",
                                             "trial", "rest")})
BAD_ROWS = ("error", "quarantine")
# How an import finds what its force sensor reads untouched (eskin.data.importer).
REST_RULES = ("low_tail", "first", "column", "rolling")
# Each rule's own keys, besides below_n.
REST_KEYS = {"low_tail": (), "first": ("rows", "seconds"), "column": (),
             "rolling": ("window_rows", "window_s")}


class Rest(Section):
    """How each file's rest force (what the sensor reads untouched) is found; a contact
    is a force above it by more than ``contact_n`` (docs/data.md#the-rest-force).

    ``low_tail`` (the default): one rest per file, from its low tail; ``first``: one per
    file, the median of its first ``rows`` rows or ``seconds`` seconds (a tare: the file
    starts untouched); ``column``: per row, the column ``columns.rest`` (the force's unit
    and sign); ``rolling``: per row, followed within the file (the low tail over
    ``window_rows`` rows or ``window_s`` seconds up to it, and from it on; the larger
    that the row does not lie below by more than ``below_n``)."""

    rule: Literal[REST_RULES] = "low_tail"  # type: ignore[valid-type]
    rows: Count | None = None
    seconds: Positive | None = None
    window_rows: Annotated[int, Field(ge=2)] | None = None
    window_s: Positive | None = None
    # A force this far below the rest (N) is no contact, not a bad row (default contact_n).
    below_n: NonNegative | None = None

    @model_validator(mode="after")
    def _rule_keys(self) -> Rest:
        own = REST_KEYS[self.rule]
        for key in (k for keys in REST_KEYS.values() for k in keys):
            if key not in own and getattr(self, key) is not None:
                rule = next(r for r, keys in REST_KEYS.items() if key in keys)
                raise ValueError(f"{key} belongs to rule: {rule}, not rule: {self.rule}")
        given = [key for key in own if getattr(self, key) is not None]
        if own and len(given) != 1:
            raise ValueError(f"rule: {self.rule} needs one of {' or '.join(own)}"
                             + (", not both" if given else ""))
        return self


class Import(Section):
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
    rest: Rest | None = None  # how the rest is found; default rule: low_tail
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
        self._check_rest()
        return self

    def _check_rest(self) -> None:
        rest, columns = self.rest, self.columns
        if rest is not None and self.contact_n is None:
            raise ValueError("rest says how the rest force is found, for the contact rule: "
                             "set import.contact_n (N) too")
        rule = rest.rule if rest is not None else "low_tail"
        if (rule == "column") != (columns.rest is not None):
            raise ValueError("columns.rest is the rest force under rest.rule: column; set "
                             "both or neither")
        timed = [key for key in ("seconds", "window_s")
                 if rest is not None and getattr(rest, key) is not None]
        if timed and columns.time is None:
            raise ValueError(f"rest.{timed[0]} counts seconds of columns.time: set it, or "
                             f"count rows ({'rows' if timed[0] == 'seconds' else 'window_rows'})")

    def position_sources(self) -> dict[str, str]:
        """{position key (x, x_mm, …): where it comes from ("column" or "name")}."""
        named = set(re.compile(self.position_from_name).groupindex) \
            if self.position_from_name else set()
        out = {key: "name" for key in POSITION_KEYS if key in named}
        columns = self.columns
        out.update({key: "column" for key in POSITION_KEYS
                    if columns is not None and getattr(columns, key) is not None})
        return out


class Scene(Section):
    """A scene: its kind, where its data come from, and the skin it is on."""

    kind: Literal[KIND_NAMES]  # type: ignore[valid-type]
    # simulated (the Python board) | emulated (the firmware under simavr: make firmware)
    # | serial (a board) | import
    source: Source
    # The skin the scene is on: {rows, columns} or {channels, grid | x_mm + y_mm}; none is
    # the paper's 10 × 10 (eskin.skin).
    skin: SkinSpec | None = None
    # What ingest does with this scene's bad rows: error | quarantine (default
    # ingest.bad_rows, every scene's).
    bad_rows: Literal[BAD_ROWS] | None = None  # type: ignore[valid-type]


class AcquiredScene(Scene):
    """A simulated, emulated or serial scene: a plan of conditions, recorded."""

    port: str | None = None      # serial: /dev/ttyACM0, socket://127.0.0.1:5000, ...
    stretches: Annotated[list[real(ge=1)], Field(min_length=1)]
    forces: Annotated[list[NonNegative], Field(min_length=1)]
    samples: Count
    # Trials per condition: the whole plan recorded this many times, each time a new trial
    # (weights placed anew). 1 is the paper's protocol.
    repeats: Count = 1
    nodes_x: list[Annotated[int, Field(ge=1)]] | None = None
    nodes_y: list[Annotated[int, Field(ge=1)]] | None = None
    # Several contacts: how many press in the plan's conditions. The paper's plan presses
    # every one (the kind's count, the default); adding 0 and 1 lets the stack learn how
    # many press (a live robot's skin is mostly untouched), at the cost of those rows.
    contact_counts: list[Annotated[int, Field(ge=0)]] | None = None

    @model_validator(mode="after")
    def _source_fields(self) -> AcquiredScene:
        if self.source == "serial" and not self.port:
            raise ValueError("source is 'serial' but port is unset")
        return self

    @model_validator(mode="after")
    def _kind_fields(self) -> AcquiredScene:
        kind = KINDS[self.kind]
        two = kind.several
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
        counts = self.contact_counts
        if counts is not None and not two:
            raise ValueError("contact_counts belongs to scenes of several contacts: a "
                             f"{kind.name} plan already records node 0 (no contact)")
        if counts is not None and (kind.contacts not in counts or max(counts) > kind.contacts
                                   or len(set(counts)) != len(counts)):
            raise ValueError(f"contact_counts {counts}: each count once, from 0 to "
                             f"{kind.contacts}, {kind.contacts} included (e.g. "
                             f"[0, 1, {kind.contacts}])")
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
                  and not (key == "force" and kind.several)]
        if others:
            raise ValueError(f"import.columns.{others[0]} is not a label of a {kind.name} "
                             f"scene ({', '.join(kind.labels)})")
        given = [force for force in kind.force_columns if getattr(columns, force) is not None]
        total = import_kind(self.kind, spec).total_force
        if total and given:
            raise ValueError(f"import.columns: force (the total) and {', '.join(given)} (per "
                             "contact) both given; keep one")
        if not total and len(given) != len(kind.force_columns):
            need = "force" if not kind.several else \
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


SceneSpec = Annotated[
    Annotated[AcquiredScene, Tag("acquired")] | Annotated[ImportedScene, Tag("imported")],
    Discriminator(_scene_source)]
# params.yaml's ``scenes``: every scene by its name.
Scenes = Annotated[dict[Annotated[str, Field(pattern=SCENE_NAME)], SceneSpec],
                   Field(min_length=1)]


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
    if declared.several and columns is not None and columns.force is not None:
        return declared.with_total_force()
    return declared


def scene_kind(scene: Scene) -> Kind:
    """The kind of scene ``scene``'s dataset: its ``kind``, or that kind's total-force
    variant where its import gives only the total (:func:`import_kind`)."""
    return import_kind(scene.kind, scene.import_ if isinstance(scene, ImportedScene) else None)


def get_scene(params: Any, name: str, path: Path | str = DEFAULT_PARAMS) -> Scene:
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
