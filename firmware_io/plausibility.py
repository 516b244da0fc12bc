"""Frames a DSA 9205 sensor cannot have sent: dropped where frames are decoded, never classified.

Why: the CRC16 lets a small share of multi-bit errors through, decoding into wrong taxels (up to 65535
in raw mode) far above any trigger level. Two rules the sensor guarantees: every value fits 12 bits,
and cells outside a pad's static mask read 0 (a 6 x 13 pad without its own mask gets the DSA 9205
distal pad's: rows 0..4 lack columns 0 and 5).
"""

from __future__ import annotations

import numpy as np

from firmware_io.layout import FULL_SCALE_12BIT, SensorLayout

__all__ = ["FrameCheck"]

DISTAL_SHAPE = (13, 6)
"""(cells_y, cells_x) of the DSA 9205 distal pad."""


def dead_cells(layout: SensorLayout) -> np.ndarray:
    """Frame columns (wire order) of cells that do not exist and must read 0."""
    distal = SensorLayout.sdh2().matrices[1].mask
    exists = [
        distal if m.static_mask is None and (m.cells_y, m.cells_x) == DISTAL_SHAPE else m.mask
        for m in layout.matrices
    ]
    return np.flatnonzero(~np.concatenate([e.ravel() for e in exists]))


class FrameCheck:
    """``problem(values)``: why a decoded frame cannot come from the sensor, or None (cheap: runs per frame)."""

    def __init__(self, layout: SensorLayout) -> None:
        self.n_taxels = layout.n_taxels
        self.dead = dead_cells(layout)
        self.limit = FULL_SCALE_12BIT

    def problem(self, values: np.ndarray) -> str | None:
        top = int(values.max()) if values.size else 0
        if top > self.limit:
            return f"value {top} above the 12-bit full scale ({self.limit})"
        if self.dead.size and values[self.dead].any():
            cell = int(self.dead[np.flatnonzero(values[self.dead])[0]])
            return f"value {int(values[cell])} on taxel {cell}, a cell the pad does not have"
        return None
