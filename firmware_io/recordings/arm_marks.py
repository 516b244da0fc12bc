"""When the robot's arm moved, stored with a recording: the marks a replay sends as the robot would.

The daemon judges every window that holds frames of the arm's motion as dormant (runtime.arm_motion);
training and evaluation must see the same spans, so a recording keeps them with its frames:

- ``meta["arm_marks"]``: ``[[frame, moving], ...]``, frame indices ascending, ``moving`` 1 at the
  first frame after the robot said ``arm moving`` and 0 at the first frame after ``arm still``
  (written by the simulator, which knows its moves, and by a recorder that heard the robot);
- without it, a recorded idle stretch labelled ``arm_move`` (``meta["source_codes"]``) counts as
  the arm moving from its first frame to its last: the investigator moved the arm when prompted.

numpy only.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np

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


def moving_frames(marks: Mapping[int, bool], n_frames: int) -> np.ndarray:
    """Per frame whether the robot's last word before it was ``arm moving`` (no settle time: that is the daemon's)."""
    out = np.zeros(n_frames, dtype=bool)
    state, since = False, 0
    for frame, moving in sorted(marks.items()):
        if state:
            out[since:frame] = True
        state, since = bool(moving), int(frame)
    if state:
        out[since:] = True
    return out
