"""The skin: how many terminals it has on each axis, what its channels are called, where
its nodes are, and what a reading is. Defined once; every channel list, grid size and
node number in eskin comes from here.

A row/column capacitive skin has R row terminals (x, along the stretch) and C column
terminals (y); each terminal is one channel, read in turn through the multiplexers, so a
frame holds R + C readings, ``cx1..cxR`` then ``cy1..cyC``. A touch sits on a node, the
crossing (x, y) with x in 1..R and y in 1..C; node 0 is no touch.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np


@dataclass(frozen=True)
class Skin:
    """A row/column skin of ``rows`` × ``columns`` terminals."""

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
    def n_nodes(self) -> int:
        return self.rows * self.columns

    def nodes(self) -> list[tuple[int, int]]:
        """Every node (x, y), x-major: (1, 1), (1, 2), …"""
        return [(x, y) for x in range(1, self.rows + 1) for y in range(1, self.columns + 1)]

    def node_id(self, x, y) -> np.ndarray:
        """Node number 1..rows·columns, x-major ((x − 1)·columns + y); 0 where x is 0 (no
        node)."""
        x = np.asarray(x, dtype=np.int64)
        y = np.asarray(y, dtype=np.int64)
        return np.where(x > 0, (x - 1) * self.columns + y, 0)


# The paper's skin: 10 x and 10 y terminals, 100 nodes (Dawood et al. 2023, Fig. 1).
PAPER_SKIN = Skin(rows=10, columns=10)
