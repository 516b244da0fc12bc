"""Helpers shared by the importers: time ordering and value checks."""

from __future__ import annotations

import numpy as np

from firmware_io.layout import FULL_SCALE_12BIT, fullscale_problem
from firmware_io.recordings.recording import RecordingError

__all__ = ["check_allocation", "check_fullscale", "check_range", "describe_timing", "keep_increasing"]

VALUES_PER_BYTE = 16
"""Most taxel values a file may decode to per byte of its (inflated) text. Why: a header may
declare any matrix size, and zero runs make a few bytes stand for millions of values; the
real SDH-2 recordings decode to at most 3.3 values a byte, so a file asking for more is
refused before anything that size is allocated."""
MAX_VALUES = 128 << 20
"""Most taxel values one recording may hold at all (the largest real file holds 8.9 million)."""
MAX_FRAMES = 1 << 20
"""Most frames one recording may hold: about 9 hours at 32 Hz, as many as a ``.hrec`` of 486 taxels holds."""


def check_allocation(n_frames: int, n_taxels: int, source_bytes: int) -> None:
    """Refuse a recording that would decode to more values than its size can hold honestly."""
    values = int(n_frames) * int(n_taxels)
    bound = min(MAX_VALUES, VALUES_PER_BYTE * int(source_bytes))
    if n_frames > MAX_FRAMES:
        raise RecordingError(f"declares {n_frames} frames; refused (at most {MAX_FRAMES}, about 9 hours at 32 Hz)")
    if values > bound:
        raise RecordingError(f"declares {n_frames} frames of {n_taxels} taxels ({values} values) from {source_bytes} "
                             f"bytes of frame data; refused (at most {VALUES_PER_BYTE} values a byte, {MAX_VALUES} in all)")


def check_fullscale(value: float, where: str) -> float:
    """A full scale a 12-bit sensor can report (1..4095), else one error naming ``where``."""
    if problem := fullscale_problem(value):
        raise RecordingError(f"{where}: {problem}")
    return value


def keep_increasing(frames: np.ndarray, stamps: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:
    """Drop frames whose time stamp does not advance, so a Recording can hold the rest.

    Duplicates and out-of-order frames are dropped rather than re-timed (an invented stamp would hide the
    fault), and counted in the recording's meta so nobody mistakes a cleaned file for a clean one.
    """
    n = len(stamps)
    info = {"duplicate_frames_dropped": 0, "out_of_order_frames_dropped": 0}
    if n < 2 or bool(np.all(np.diff(stamps) > 0)):
        return frames, stamps, info
    keep = np.zeros(n, dtype=bool)
    keep[0] = True
    last = 0
    for i in range(1, n):
        if stamps[i] > stamps[last]:
            keep[i] = True
            last = i
        elif stamps[i] == stamps[last] and np.array_equal(frames[i], frames[last]):
            info["duplicate_frames_dropped"] += 1
        else:
            info["out_of_order_frames_dropped"] += 1
    return frames[keep], stamps[keep], info


def check_range(values: np.ndarray, fullscale: float, unit: str = "frame") -> None:
    """Refuse values that cannot be raw 12-bit taxel readings; names the first bad frame and taxel."""
    if values.size == 0:
        return
    top = min(float(fullscale), FULL_SCALE_12BIT)
    bad = (values < 0) | (values > top)
    if bad.any():
        f, c = np.argwhere(bad)[0]
        raise RecordingError(f"{unit} {f}, taxel {c}: value {values[f, c]:g} outside 0..{top:g}")


def describe_timing(stamps: np.ndarray) -> dict:
    """Rate figures for the meta block and the import summary line."""
    if len(stamps) < 2:
        return {"frame_interval_median_s": None, "gaps_over_1s": 0}
    d = np.diff(stamps)
    return {
        "frame_interval_median_s": float(np.median(d)),
        "gaps_over_1s": int(np.sum(d > 1.0)),
    }
