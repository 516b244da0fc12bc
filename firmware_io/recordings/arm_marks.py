"""When the robot's arm moved, stored with a recording: the marks a replay sends as the robot would.

The daemon judges windows holding the arm's motion dormant (runtime.arm_motion), so training sees the
same spans: ``meta["arm_marks"]`` is ``[[frame, moving], ...]`` (1 from the frame after "arm moving",
0 after "arm still"); without it an idle stretch labelled ``arm_move`` counts as moving throughout.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence

import numpy as np

__all__ = ["KEY", "encode", "marks_of", "problem"]

KEY = "arm_marks"
ARM_SOURCE = "arm_move"


def encode(marks: Mapping[int, bool]) -> list[list[int]]:
    """``{frame: moving}`` as stored in ``meta[KEY]`` (ascending frames, 0/1)."""
    return [[int(f), int(bool(m))] for f, m in sorted(marks.items())]


def problem(meta: Mapping, n_frames: int) -> str | None:
    """Why ``meta[KEY]`` cannot be used with ``n_frames`` frames, or None (also when absent)."""
    raw = meta.get(KEY)
    if raw is None:
        return None
    if not isinstance(raw, list):
        return f"meta.{KEY} must be a list of [frame, moving] pairs"
    last = -1
    for item in raw:
        if (not isinstance(item, list) or len(item) != 2 or not all(isinstance(x, int) and not isinstance(x, bool)
                                                                    for x in item) or item[1] not in (0, 1)):
            return f"meta.{KEY}: {item!r} is not a [frame, 0 or 1] pair"
        if not last < item[0] < n_frames:
            return f"meta.{KEY}: frame {item[0]} is out of order or outside 0..{n_frames - 1}"
        last = item[0]
    return None


def marks_of(meta: Mapping, n_frames: int) -> dict[int, bool]:
    """Frame -> moving, as the robot would have said it: the stored marks, else the ``arm_move`` stretches.

    Raises ValueError (naming the key) for stored marks that do not fit the recording."""
    why = problem(meta, n_frames)
    if why:
        raise ValueError(why)
    if meta.get(KEY) is not None:
        return {int(f): bool(m) for f, m in meta[KEY]}
    return stretch_marks(meta.get("source_codes"), meta.get("sources", ()))


def piece_marks(meta: Mapping, n_frames: int, first: int, last: int) -> list[list[int]]:
    """The recording's marks (``marks_of``) of frames ``first..last``, counted from ``first`` (stored form):
    for replaying a piece on its own, the arm's state at ``first`` carried in."""
    marks = marks_of(meta, n_frames)
    before = [m for f, m in marks.items() if f <= first]
    out = {0: before[-1]} if before and before[-1] else {}
    out.update({f - first: m for f, m in marks.items() if first < f <= last})
    return encode(out)


def stretch_marks(codes: Iterable[int] | None, names: Iterable[str]) -> dict[int, bool]:
    """Marks of the frames coded ``arm_move``: moving at each run's first frame, still after its last."""
    names = list(names)
    if codes is None or ARM_SOURCE not in names:
        return {}
    moving = np.asarray(list(codes) if not isinstance(codes, np.ndarray) else codes,
                        dtype=np.int64) == names.index(ARM_SOURCE)
    if not moving.any():
        return {}
    edges = np.diff(np.concatenate([[0], moving.astype(np.int8), [0]]))
    out = {int(i): True for i in np.flatnonzero(edges == 1)}
    out.update({int(i): False for i in np.flatnonzero(edges == -1) if i < len(moving)})
    return dict(sorted(out.items()))


class ArmMarkLog:
    """What the robot said about its arm while a session was recorded, turned into each segment's marks.

    ``note`` is called from the control socket's thread with each ``arm moving`` / ``arm still``; only
    changes are kept (a flood of the same word is one entry). ``marks_for`` places them on a captured
    segment by the frames' arrival times (the same clock), its first frame carrying the arm's state
    then (a move that began before the segment)."""

    def __init__(self, clock: Callable[[], float] = time.perf_counter) -> None:
        self._clock = clock
        self._lock = threading.Lock()
        self._times: list[float] = []
        self._words: list[bool] = []
        self.heard = 0
        """Arm messages heard (repeats included)."""

    def note(self, moving: bool, source: str = "") -> None:
        now = self._clock()
        with self._lock:
            self.heard += 1
            if not self._words or self._words[-1] != bool(moving):
                self._times.append(now)
                self._words.append(bool(moving))

    def marks_for(self, received: Sequence[float] | None) -> list[list[int]]:
        """``[[frame, moving], ...]`` of a segment whose frames arrived at ``received`` (empty if nothing was heard)."""
        with self._lock:
            times, words = list(self._times), list(self._words)
        if not words or received is None or len(received) == 0:
            return []
        arrived = np.asarray(received, dtype=np.float64)
        k = int(np.searchsorted(times, arrived[0], side="right"))  # words said before the first frame
        out = {0: words[k - 1] if k else False}
        for t, word in zip(times[k:], words[k:], strict=True):
            if t > arrived[-1]:
                break
            out[min(int(np.searchsorted(arrived, t, side="left")), len(arrived) - 1)] = word
        return encode(out)
