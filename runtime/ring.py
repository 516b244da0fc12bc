"""A preallocated ring buffer of only the scene's taxel columns.

Each frame is written twice, at ``i`` and ``i + capacity`` of a ``[2 * capacity, C]`` array,
so the last T frames are always one contiguous slice: ``window(T)`` is a view, no copy and no
gather on the hot path. Columns of pads outside the scene are never touched: a push copies
only the scene's contiguous column runs from the wire-order frame.
"""

from __future__ import annotations

import numpy as np

__all__ = ["RingBuffer", "column_runs"]


def column_runs(columns: np.ndarray) -> tuple[tuple[int, int, int, int], ...]:
    """Contiguous runs of frame columns as (src_start, src_stop, dst_start, dst_stop)."""
    cols = np.asarray(columns, dtype=np.int64)
    if cols.ndim != 1 or cols.size == 0:
        raise ValueError("columns must be a non-empty 1-D index array")
    runs = []
    start = 0
    for i in range(1, cols.size + 1):
        if i == cols.size or cols[i] != cols[i - 1] + 1:
            runs.append((int(cols[start]), int(cols[i - 1]) + 1, start, i))
            start = i
    return tuple(runs)


class RingBuffer:
    """The last ``capacity`` frames of the scene's columns, as float32."""

    def __init__(self, columns: np.ndarray, capacity: int) -> None:
        if capacity < 1:
            raise ValueError("capacity must be >= 1")
        self.columns = np.asarray(columns, dtype=np.int64)
        self._runs = column_runs(self.columns)
        self.capacity = int(capacity)
        self.n_channels = int(self.columns.size)
        self._buf = np.zeros((2 * self.capacity, self.n_channels), dtype=np.float32)
        self._pos = 0  # next row to write, in [0, capacity)
        self.count = 0
        """Frames pushed since the last reset."""
        self.last_number = -1
        """Frame number of the newest frame (caller supplied)."""

    def reset(self) -> None:
        """Forget the history (after a reconnect the stream is not continuous)."""
        self._pos = 0
        self.count = 0
        self.last_number = -1

    def push(self, values: np.ndarray, number: int = -1) -> None:
        """Store one wire-order frame's scene columns. O(C), no allocation."""
        buf, pos, cap = self._buf, self._pos, self.capacity
        row_a = buf[pos]
        row_b = buf[pos + cap]
        for src0, src1, dst0, dst1 in self._runs:
            row_a[dst0:dst1] = values[src0:src1]
        row_b[:] = row_a
        self._pos = pos + 1 if pos + 1 < cap else 0
        self.count += 1
        self.last_number = number

    def latest(self) -> np.ndarray:
        """The newest frame's scene columns (a view)."""
        return self._buf[self._pos - 1 + self.capacity]

    def window(self, length: int, end_offset: int = 0) -> np.ndarray:
        """A ``[1, length, C]`` float32 view of the frames ending ``end_offset`` frames ago.

        ``end_offset = 0`` ends at the newest frame. The view stays valid until
        ``capacity - length - end_offset`` more frames are pushed.
        """
        if not 0 < length + end_offset <= self.capacity:
            raise ValueError(f"window of {length} (+{end_offset}) frames exceeds capacity {self.capacity}")
        if length + end_offset > self.count:
            raise ValueError(f"window of {length} frames needs {length + end_offset} pushed, have {self.count}")
        stop = self._pos + self.capacity - end_offset
        return self._buf[stop - length : stop][np.newaxis]

    def resized(self, capacity: int) -> RingBuffer:
        """A new ring of another capacity holding as much of this history as fits."""
        new = RingBuffer(self.columns, capacity)
        keep = min(self.count, capacity, self.capacity)
        if keep:
            new._buf[:keep] = self.window(keep)[0]
            new._buf[capacity : capacity + keep] = new._buf[:keep]
            new._pos = keep % capacity
        new.count = keep
        new.last_number = self.last_number
        return new
