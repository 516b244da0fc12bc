"""Sensor layout: which tactile matrices a controller has and where each taxel sits in a frame.

A frame is all taxel values in wire order: matrices in index order, each row-major with x
(column) fastest. Sizes come from the controller (query 0x0B) or from a recording; the SDH-2
default exists for simulation and for files that carry no header.
"""

from __future__ import annotations

import numbers
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from firmware_io.errors import HandoverError

__all__ = ["FULL_SCALE_12BIT", "LayoutError", "MatrixInfo", "SensorLayout", "fullscale_problem"]

FULL_SCALE_12BIT = 4095


def fullscale_problem(value: object) -> str | None:
    """Why ``value`` cannot be a pad's full scale, or None. Trigger levels, the onset floor and the
    level features are fractions of it: 0 or NaN made them divide by zero in the hot path, and 1e308
    overflowed the controller's float32 reply; a 12-bit pad reports 1 to 4095."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not 1 <= value <= FULL_SCALE_12BIT:
        return f"fullscale {value!r} is not a 12-bit pad's full scale (a number from 1 to {FULL_SCALE_12BIT})"
    return None


class LayoutError(HandoverError, ValueError):
    """A layout or a pad selection that does not fit the sensor."""


@dataclass(frozen=True)
class MatrixInfo:
    """One tactile pad as the controller describes it (reply to 0x0B)."""

    index: int
    cells_x: int
    cells_y: int
    texel_width: float = 3.4
    texel_height: float = 3.4
    center: tuple[float, float, float] = (0.0, 0.0, 0.0)
    fullscale: float = float(FULL_SCALE_12BIT)
    static_mask: np.ndarray | None = field(default=None, compare=False)
    """Boolean ``(cells_y, cells_x)``: True where a taxel exists. None means all exist."""

    def __post_init__(self) -> None:
        if self.cells_x <= 0 or self.cells_y <= 0:
            raise LayoutError(f"matrix {self.index}: cells must be positive, got {self.cells_x}x{self.cells_y}")
        if problem := fullscale_problem(self.fullscale):
            raise LayoutError(f"matrix {self.index}: {problem}")
        if self.static_mask is not None:
            mask = np.asarray(self.static_mask, dtype=bool)
            if mask.shape != (self.cells_y, self.cells_x):
                raise LayoutError(
                    f"matrix {self.index}: static mask shape {mask.shape} != ({self.cells_y}, {self.cells_x})"
                )
            object.__setattr__(self, "static_mask", mask)

    @property
    def n_cells(self) -> int:
        return self.cells_x * self.cells_y

    @property
    def mask(self) -> np.ndarray:
        """Boolean ``(cells_y, cells_x)`` mask of existing taxels (all True when none is stored)."""
        if self.static_mask is None:
            return np.ones((self.cells_y, self.cells_x), dtype=bool)
        return self.static_mask

    def to_dict(self) -> dict:
        return {
            "index": self.index,
            "cells_x": self.cells_x,
            "cells_y": self.cells_y,
            "texel_width": self.texel_width,
            "texel_height": self.texel_height,
            "center": list(self.center),
            "fullscale": self.fullscale,
            "static_mask": None if self.static_mask is None else self.static_mask.astype(int).tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict) -> MatrixInfo:
        mask = d.get("static_mask")
        fullscale = d.get("fullscale", FULL_SCALE_12BIT)
        if problem := fullscale_problem(fullscale):  # before float(): null, "abc" or true are no full scale
            raise LayoutError(f"matrix {d.get('index')}: {problem}")
        return cls(
            index=int(d["index"]),
            cells_x=int(d["cells_x"]),
            cells_y=int(d["cells_y"]),
            texel_width=float(d.get("texel_width", 3.4)),
            texel_height=float(d.get("texel_height", 3.4)),
            center=tuple(float(v) for v in d.get("center", (0.0, 0.0, 0.0))),
            fullscale=float(fullscale),
            static_mask=None if mask is None else np.asarray(mask, dtype=bool),
        )


def _distal_mask(cells_x: int = 6, cells_y: int = 13) -> np.ndarray:
    mask = np.ones((cells_y, cells_x), dtype=bool)
    mask[:5, 0] = False
    mask[:5, cells_x - 1] = False
    return mask


@dataclass(frozen=True)
class SensorLayout:
    """All matrices of one controller, in wire order."""

    matrices: tuple[MatrixInfo, ...]

    def __post_init__(self) -> None:
        if not self.matrices:
            raise LayoutError("a layout needs at least one matrix")
        for i, m in enumerate(self.matrices):
            if m.index != i:
                raise LayoutError(f"matrix at position {i} has index {m.index}; matrices must be in index order")

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def sdh2(cls) -> SensorLayout:
        """The SDH / SDH-2 default: proximal 6x14 at 0, 2, 4; distal 6x13 at 1, 3, 5 (486 taxels)."""
        centers = [(-50.0, -32.0), (-50.0, 32.0), (0.0, -32.0), (0.0, 32.0), (50.0, -32.0), (50.0, 32.0)]
        mats = []
        for i, (cx, cy) in enumerate(centers):
            distal = i % 2 == 1
            mats.append(
                MatrixInfo(
                    index=i,
                    cells_x=6,
                    cells_y=13 if distal else 14,
                    center=(cx, cy, 0.0),
                    static_mask=_distal_mask() if distal else None,
                )
            )
        return cls(tuple(mats))

    @classmethod
    def from_matrix_infos(cls, infos: Iterable[MatrixInfo]) -> SensorLayout:
        """Build from the controller's per-matrix replies (any order)."""
        return cls(tuple(sorted(infos, key=lambda m: m.index)))

    def to_dict(self) -> dict:
        return {"matrices": [m.to_dict() for m in self.matrices]}

    @classmethod
    def from_dict(cls, d: dict) -> SensorLayout:
        try:
            return cls(tuple(MatrixInfo.from_dict(m) for m in d["matrices"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise LayoutError(f"invalid layout description: {exc}") from exc

    # -- geometry -----------------------------------------------------------------------------
    @property
    def n_matrices(self) -> int:
        return len(self.matrices)

    @property
    def n_taxels(self) -> int:
        return sum(m.n_cells for m in self.matrices)

    @property
    def offsets(self) -> tuple[int, ...]:
        """Start of each matrix in a frame."""
        out, pos = [], 0
        for m in self.matrices:
            out.append(pos)
            pos += m.n_cells
        return tuple(out)

    @property
    def fullscale(self) -> float:
        return max(m.fullscale for m in self.matrices)

    def matrix_slice(self, index: int) -> slice:
        start = self.offsets[index]
        return slice(start, start + self.matrices[index].n_cells)

    def static_mask(self) -> np.ndarray:
        """Boolean mask over a whole frame: True where a taxel physically exists."""
        return np.concatenate([m.mask.ravel() for m in self.matrices])

    def is_proximal(self, index: int) -> bool:
        return index % 2 == 0

    # -- pad selections -----------------------------------------------------------------------
    def pads(self, selection: str | Sequence[int] | int) -> tuple[int, ...]:
        """Resolve a pad selection to matrix indices.

        Names: ``all``, ``distal``, ``proximal``, ``thumb``, ``thumb-distal``, ``thumb-proximal``,
        ``finger-N`` / ``finger-N-distal`` / ``finger-N-proximal`` (N = 0, 1, 2 in matrix order;
        the SDH thumb is finger 1, matrices 2 and 3), or indices such as ``"1,3,5"`` or ``[1, 3]``.
        """
        n = self.n_matrices
        if isinstance(selection, int):
            selection = [selection]
        if isinstance(selection, str):
            name = selection.strip().lower()
            if not name:
                raise LayoutError("empty pad selection")
            if all(part.strip().isdigit() for part in name.split(",")):
                idx = [int(p) for p in name.split(",")]
            elif name == "all":
                idx = list(range(n))
            elif name == "distal":
                idx = [i for i in range(n) if i % 2 == 1]
            elif name == "proximal":
                idx = [i for i in range(n) if i % 2 == 0]
            else:
                idx = self._finger_pads(name)
        else:
            idx = [int(i) for i in selection]
        if not idx:
            raise LayoutError(f"pad selection {selection!r} is empty")
        bad = [i for i in idx if not 0 <= i < n]
        if bad:
            raise LayoutError(f"pad selection {selection!r}: no matrix {bad[0]} (sensor has {n})")
        if len(set(idx)) != len(idx):
            raise LayoutError(f"pad selection {selection!r} names a pad twice")
        return tuple(sorted(idx))

    def pad_name(self, index: int) -> str:
        """The selection name of one pad: ``finger-0-proximal``, ``thumb-distal`` ... (the SDH thumb
        is finger 1); the index as text when the matrices do not pair up into fingers.
        ``pads(pad_name(i)) == (i,)``."""
        if not 0 <= index < self.n_matrices:
            raise LayoutError(f"no matrix {index} (sensor has {self.n_matrices})")
        if self.n_matrices % 2:
            return str(index)
        finger, part = self.finger_of(index), index % 2
        who = "thumb" if finger == 1 else f"finger-{finger}"
        return f"{who}-{'distal' if part else 'proximal'}"

    def selection_name(self, pads: Sequence[int]) -> str | None:
        """The name that selects exactly these pads (``all``, ``distal``, ``proximal``, ``thumb``), or None."""
        for name in ("all", "distal", "proximal", "thumb"):
            try:
                if list(self.pads(name)) == [int(p) for p in pads]:
                    return name
            except LayoutError:
                pass
        return None

    def finger_of(self, index: int) -> int:
        """The finger a pad sits on: matrices pair up as (proximal, distal) per finger (SDH-2);
        when they do not pair up, every pad counts as a finger of its own."""
        return index if self.n_matrices % 2 else index // 2

    def pad_fingers(self, selection: str | Sequence[int] | int) -> tuple[int, ...]:
        """The finger of each selected pad, in order (``finger_of``)."""
        return tuple(self.finger_of(p) for p in self.pads(selection))

    def _finger_pads(self, name: str) -> list[int]:
        parts = name.split("-")
        if parts[0] == "thumb":
            finger, rest = 1, parts[1:]
        elif parts[0] == "finger" and len(parts) >= 2 and parts[1].isdigit():
            finger, rest = int(parts[1]), parts[2:]
        else:
            raise LayoutError(
                f"unknown pad selection {name!r}; use all, distal, proximal, thumb[-distal|-proximal], "
                "finger-N[-distal|-proximal] or indices like 1,3,5"
            )
        if rest == []:
            return [2 * finger, 2 * finger + 1]
        if rest == ["distal"]:
            return [2 * finger + 1]
        if rest == ["proximal"]:
            return [2 * finger]
        raise LayoutError(f"unknown pad selection {name!r}")

    def columns(self, selection: str | Sequence[int] | int) -> np.ndarray:
        """Frame column indices (wire order) of the selected pads, as an int64 array."""
        pads = self.pads(selection)
        return np.concatenate([np.arange(self.matrix_slice(p).start, self.matrix_slice(p).stop) for p in pads])

    def pad_sizes(self, selection: str | Sequence[int] | int) -> tuple[int, ...]:
        """Number of taxel columns of each selected pad, in order (for per-pad features)."""
        return tuple(self.matrices[p].n_cells for p in self.pads(selection))

    def subset(self, selection: str | Sequence[int] | int) -> SensorLayout:
        """Layout of only the selected pads, renumbered 0..n-1 (what a scene's ring buffer holds)."""
        mats = []
        for new, p in enumerate(self.pads(selection)):
            m = self.matrices[p]
            mats.append(
                MatrixInfo(new, m.cells_x, m.cells_y, m.texel_width, m.texel_height, m.center, m.fullscale, m.static_mask)
            )
        return SensorLayout(tuple(mats))
