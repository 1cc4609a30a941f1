"""The skin: what its channels are called, where a touch can sit, and what a reading is.
Defined once; every channel list, grid size and node number in eskin comes from here.

Two layouts, both declared per scene in params.yaml (``scenes.<s>.skin``):

* :class:`Skin`, a row/column capacitive skin of R row terminals (x, along the stretch)
  and C column terminals (y). Each terminal is one channel, read in turn through the
  multiplexers, so a frame holds R + C readings, ``cx1..cxR`` then ``cy1..cyC``. A touch
  sits on a node, the crossing (x, y) with x in 1..R and y in 1..C.
* :class:`ChannelArray`, N named channels (taxels, magnetometers, ...) read at once, and
  a grid of press positions: x in 1..size_x, y in 1..size_y, optionally placed in mm.

Both answer the same questions (``channels``, ``size_x``, ``size_y``, ``nodes()``,
``node_id``), so the learning and reporting side need not know which it has. Node 0 is
no touch. A scene with no ``skin`` is on :data:`PAPER_SKIN`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np


class _Grid:
    """Where a touch can sit: nodes (x, y), x in 1..size_x and y in 1..size_y."""

    size_x: int
    size_y: int

    @property
    def n_nodes(self) -> int:
        return self.size_x * self.size_y

    def nodes(self) -> list[tuple[int, int]]:
        """Every node (x, y), x-major: (1, 1), (1, 2), …"""
        return [(x, y) for x in range(1, self.size_x + 1) for y in range(1, self.size_y + 1)]

    def node_id(self, x, y) -> np.ndarray:
        """Node number 1..size_x·size_y, x-major ((x − 1)·size_y + y); 0 where x is 0 (no
        node)."""
        x = np.asarray(x, dtype=np.int64)
        y = np.asarray(y, dtype=np.int64)
        return np.where(x > 0, (x - 1) * self.size_y + y, 0)


@dataclass(frozen=True)
class Skin(_Grid):
    """A row/column skin of ``rows`` × ``columns`` terminals."""

    row_column = True  # physics features, protocol v1 and the firmware apply

    rows: int
    columns: int
    # What a channel carries: the CAV424's voltage through the board's 10-bit ADC.
    readout: str = "ADC counts (CAV424 capacitance-to-voltage, 10-bit)"

    def __post_init__(self) -> None:
        for name in ("rows", "columns"):
            if not 2 <= getattr(self, name) <= 32:
                raise ValueError(f"a skin has 2 to 32 {name}, got {getattr(self, name)}")

    @property
    def terminals(self) -> int:
        """Channels per frame (protocol v1's ``terminals=<N>``)."""
        return self.rows + self.columns

    @cached_property
    def x_channels(self) -> list[str]:
        return [f"cx{i}" for i in range(1, self.rows + 1)]

    @cached_property
    def y_channels(self) -> list[str]:
        return [f"cy{i}" for i in range(1, self.columns + 1)]

    @cached_property
    def channels(self) -> list[str]:
        return self.x_channels + self.y_channels

    @property
    def size_x(self) -> int:
        """Node positions along x: one per row terminal."""
        return self.rows

    @property
    def size_y(self) -> int:
        return self.columns

    # No physical pitch is declared for a row/column skin: positions are in nodes.
    x_mm: tuple[float, ...] | None = field(default=None, init=False, repr=False, compare=False)
    y_mm: tuple[float, ...] | None = field(default=None, init=False, repr=False, compare=False)

    def describe(self) -> str:
        return f"{self.rows} × {self.columns} row/column skin ({self.terminals} terminals)"

    def as_dict(self) -> dict[str, object]:
        """As params.yaml declares it (and a dataset's ``eskin.skin`` metadata records it)."""
        return {"rows": self.rows, "columns": self.columns}


@dataclass(frozen=True)
class ChannelArray(_Grid):
    """``channels`` named channels read at once, pressed on a ``size_x`` × ``size_y`` grid
    of positions; ``x_mm``/``y_mm``, when given, place each grid line in millimetres (a
    position's x is the index of its x coordinate among ``x_mm``, 1-based)."""

    names: tuple[str, ...]
    size_x: int
    size_y: int
    x_mm: tuple[float, ...] | None = None
    y_mm: tuple[float, ...] | None = None
    readout: str = "as recorded (the instrument's own unit)"

    row_column = False

    def __post_init__(self) -> None:
        if len(self.names) < 1:
            raise ValueError("a channel array has at least one channel")
        if len(set(self.names)) != len(self.names):
            raise ValueError("a channel array's channel names must differ")
        for name in ("size_x", "size_y"):
            if not 1 <= getattr(self, name) <= 64:
                raise ValueError(f"a channel array's grid has 1 to 64 positions along "
                                 f"{name[-1]}, got {getattr(self, name)}")
        for axis, size in (("x", self.size_x), ("y", self.size_y)):
            coords = getattr(self, f"{axis}_mm")
            if coords is not None and (len(coords) != size or list(coords) != sorted(coords)):
                raise ValueError(f"{axis}_mm must list {size} increasing coordinates")

    @cached_property
    def channels(self) -> list[str]:
        return list(self.names)

    @property
    def terminals(self) -> int:
        """Channels per frame."""
        return len(self.names)

    def describe(self) -> str:
        return (f"array of {len(self.names)} channels, {self.size_x} × {self.size_y} "
                "press positions")

    def as_dict(self) -> dict[str, object]:
        out: dict[str, object] = {"channels": list(self.names),
                                  "grid": [self.size_x, self.size_y]}
        if self.x_mm is not None:
            out["x_mm"] = list(self.x_mm)
        if self.y_mm is not None:
            out["y_mm"] = list(self.y_mm)
        return out


AnySkin = Skin | ChannelArray


def skin_from_dict(spec: dict | None) -> AnySkin:
    """The skin a params ``skin`` section (or a dataset's ``eskin.skin``) declares; the
    paper's skin when there is none."""
    if not spec:
        return PAPER_SKIN
    if "channels" in spec:
        grid = spec.get("grid")
        x_mm, y_mm = spec.get("x_mm"), spec.get("y_mm")
        size_x = len(x_mm) if grid is None and x_mm is not None else (grid or [1, 1])[0]
        size_y = len(y_mm) if grid is None and y_mm is not None else (grid or [1, 1])[1]
        return ChannelArray(tuple(spec["channels"]), int(size_x), int(size_y),
                            None if x_mm is None else tuple(float(v) for v in x_mm),
                            None if y_mm is None else tuple(float(v) for v in y_mm))
    return Skin(int(spec["rows"]), int(spec["columns"]))


def skin_of_columns(columns) -> Skin:
    """The row/column skin whose channels a dataset's ``cx*``/``cy*`` columns spell: how a
    dataset that records no ``eskin.skin`` (the paper's skin's, kept byte for byte) is read."""
    rows = sum(1 for c in columns if str(c).startswith("cx") and str(c)[2:].isdigit())
    cols = sum(1 for c in columns if str(c).startswith("cy") and str(c)[2:].isdigit())
    return Skin(rows, cols)


# The paper's skin: 10 x and 10 y terminals, 100 nodes (Dawood et al. 2023, Fig. 1).
PAPER_SKIN = Skin(rows=10, columns=10)
