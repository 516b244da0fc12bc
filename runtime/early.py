"""Early decisions: what a model file says about its early heads, and the rule that reports from them.

Why: the full window makes the robot wait about half a second, while a firm pull is plain after a few
frames. Early heads are extra outputs of the same graph (``label_at_<p>``, ``scores_at_<p>``), each
trained on the first ``p`` frames of the window (the LAST ``p`` rows of its input, so the ring's newest
T frames serve every point). The metadata key ``early`` (``EarlySpec``; docs/EARLY.md) holds the points,
each head's Platt calibration of its score margin, the probability ``threshold`` to report at and
whether a head must ``agree`` with the previous one; at T the full model answers, always.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from firmware_io.errors import HandoverError
from runtime.decision import margin_of

__all__ = [
    "EARLY_KEY", "NEVER", "EarlyRule", "EarlySpec", "EarlySpecError", "head_outputs", "is_head_output"
]

EARLY_KEY = "early"
"""The metadata key of the early heads (absent: a model without early heads, served as before)."""
LABEL_PREFIX, SCORES_PREFIX = "label_at_", "scores_at_"
MAX_POINTS = 16
"""The most early heads a model may carry: each one is a session of its own (load time and memory per
head), so a file claiming hundreds would hold the model watcher (and ``run --check``) for minutes
before its warm-up could refuse it; training fits a handful (trainer.early.EARLY_POINTS)."""
NEVER = 1.01
"""A threshold above every probability: the rule that always waits for T (what training chooses when no
early rule keeps the accuracy)."""


def head_outputs(point: int) -> tuple[str, str]:
    """The graph's output names of the head that decides ``point`` frames into the window."""
    return f"{LABEL_PREFIX}{point}", f"{SCORES_PREFIX}{point}"


def is_head_output(name: str) -> bool:
    return name.startswith((LABEL_PREFIX, SCORES_PREFIX))


class EarlySpecError(HandoverError, ValueError):
    """Early-head metadata that is inconsistent; the message says what and what to do."""


@dataclass(frozen=True)
class EarlySpec:
    """The early heads of a model and the rule chosen for them (see the module docstring)."""

    points: tuple[int, ...]
    calibration: tuple[tuple[float, float], ...]
    threshold: float
    agree: bool
    classes: tuple[str, ...] | None = None
    """The classes training allows to be reported early (None: every reported class); the others wait for T."""

    @classmethod
    def from_meta(cls, value: object, T: int, class_names: Sequence[str] | None = None) -> EarlySpec:
        """Validate the ``early`` metadata object against the window length ``T`` (and the model's
        ``class_names``: a name it lacks would keep that class to T, silently)."""
        if not isinstance(value, dict):
            raise EarlySpecError(f"{EARLY_KEY} must be an object, got {type(value).__name__}")
        points, calib = value.get("points"), value.get("calibration")
        threshold, agree = value.get("threshold"), value.get("agree")
        if (not isinstance(points, list) or not points
                or any(isinstance(p, bool) or not isinstance(p, int) for p in points)):
            raise EarlySpecError(f"{EARLY_KEY}.points must be a non-empty list of frame counts, got {points!r}")
        if len(points) > MAX_POINTS:
            raise EarlySpecError(f"{EARLY_KEY}.points lists {len(points)} heads, at most {MAX_POINTS} are served; "
                                 "train with fewer early points")
        if sorted(set(points)) != points or points[0] < 2 or points[-1] >= T:
            raise EarlySpecError(f"{EARLY_KEY}.points {points} must ascend, each from 2 to T-1={T - 1}")
        if (not isinstance(calib, list) or len(calib) != len(points)
                or any(not isinstance(c, list) or len(c) != 2 or not all(_finite(x) for x in c) for c in calib)):
            raise EarlySpecError(f"{EARLY_KEY}.calibration must hold one [a, b] pair of numbers per point "
                                 f"({len(points)}); re-export the model")
        if not _finite(threshold) or not 0.0 <= float(threshold) <= NEVER:
            raise EarlySpecError(f"{EARLY_KEY}.threshold must be a probability (or {NEVER}: never early), "
                                 f"got {threshold!r}")
        if not isinstance(agree, bool):
            raise EarlySpecError(f"{EARLY_KEY}.agree must be true or false, got {agree!r}")
        classes = value.get("classes")
        if classes is not None and (not isinstance(classes, list) or not all(isinstance(c, str) for c in classes)):
            raise EarlySpecError(f"{EARLY_KEY}.classes must be a list of class names (or absent), got {classes!r}")
        if classes is not None and class_names is not None and (alien := [c for c in classes if c not in class_names]):
            raise EarlySpecError(f"{EARLY_KEY}.classes names {', '.join(map(repr, alien))}, not a class of the model "
                                 f"({', '.join(class_names)}); re-export the model")
        return cls(tuple(points), tuple((float(a), float(b)) for a, b in calib), float(threshold), agree,
                   None if classes is None else tuple(classes))

    def to_meta(self) -> dict:
        return {"points": list(self.points), "calibration": [list(c) for c in self.calibration],
                "threshold": self.threshold, "agree": self.agree,
                **({} if self.classes is None else {"classes": list(self.classes)})}

    def needs(self, class_names: Sequence[str], dormant: str | None = None) -> np.ndarray:
        """The confidence each class (by index) needs to be reported early: ``threshold``, or ``NEVER`` for
        a class training keeps to T and for ``dormant`` (a dormant answer leaves the window to the next
        head, or to T)."""
        return np.asarray([NEVER if c == dormant or (self.classes is not None and c not in self.classes)
                           else self.threshold for c in class_names])

    def confidence(self, index: int, scores: np.ndarray, label: int) -> float:
        """Calibrated probability that head ``index`` (of ``points``) is right, from one row of scores."""
        a, b = self.calibration[index]
        return _sigmoid(a * margin_of(scores.reshape(-1), label) + b)


def _finite(x: object) -> bool:
    return not isinstance(x, bool) and isinstance(x, int | float) and math.isfinite(x)


def _sigmoid(z: float) -> float:
    return 1.0 / (1.0 + math.exp(-z)) if z >= 0 else math.exp(z) / (1.0 + math.exp(z))


class EarlyRule:
    """One event's early decisions: per point, whether to report now (one report per event).

    ``early_classes``: the classes (by name) the scene lets come before T (None: all); a scene that must
    release on a pull but may wait on a bump lists only ``pull`` (``scene.early_events``)."""

    def __init__(self, spec: EarlySpec, class_names: Sequence[str], early_classes: frozenset[str] | None = None
                 ) -> None:
        self.spec = spec
        self._need = [NEVER if early_classes is not None and c not in early_classes else need
                      for c, need in zip(class_names, spec.needs(class_names), strict=True)]
        self._index = {p: i for i, p in enumerate(spec.points)}

    def index_of(self, point: int) -> int:
        """Position of ``point`` in the spec's points, or -1 when no head decides there."""
        return self._index.get(point, -1)

    def report_now(self, index: int, label: int, scores: np.ndarray, previous: int) -> bool:
        """Whether head ``index``'s answer ``label`` is safe to report (``previous``: the label of the
        head before it for this event, -1 when none)."""
        if not 0 <= label < len(self._need) or self._need[label] >= NEVER:
            return False
        if self.spec.agree and label != previous:
            return False
        return self.spec.confidence(index, scores, label) >= self._need[label]
