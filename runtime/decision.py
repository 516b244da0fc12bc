"""When continuous mode reports: from one decision per frame to one report per interaction.

Why: reporting every change of a per-frame decision fires on partial first windows and on every
flicker. A non-dormant class is *confirmed* after winning ``confirm_frames`` frames in a row with a
margin of at least ``min_margin`` (``gap_frames`` dormant frames do not break the run; with ``vote``
the run is any non-dormant class and its most frequent one is reported). A report disarms the rule
until dormant has won ``rearm_frames`` in a row (0: never disarms). O(n_classes) per frame.
"""

from __future__ import annotations

import numpy as np

__all__ = ["ContinuousDecision", "margin_of"]


class ContinuousDecision:
    """Per-frame labels and scores in, the class index to report (or -1) out."""

    def __init__(self, n_classes: int, dormant: int, confirm_frames: int = 1, min_margin: float = 0.0,
                 rearm_frames: int = 0, gap_frames: int = 0, vote: bool = False) -> None:
        if not 0 <= dormant < n_classes:
            raise ValueError(f"dormant class index {dormant} is not one of {n_classes} classes")
        if confirm_frames < 1:
            raise ValueError("confirm_frames must be >= 1")
        if min_margin < 0:
            raise ValueError("min_margin must be >= 0")
        if rearm_frames < 0:
            raise ValueError("rearm_frames must be >= 0")
        if gap_frames < 0:
            raise ValueError("gap_frames must be >= 0")
        self.n_classes = int(n_classes)
        self.dormant = int(dormant)
        self.confirm_frames = int(confirm_frames)
        self.min_margin = float(min_margin)
        self.rearm_frames = int(rearm_frames)
        self.gap_frames = int(gap_frames)
        self.vote = bool(vote)
        self._votes = [0] * self.n_classes
        self.reset()

    def reset(self) -> None:
        """Armed, no history (after a reconnect or a model change)."""
        self.candidate = -1
        self.run = 0
        self.dormant_run = 0
        self.armed = True
        self.last_reported = -1
        self.margin = 0.0
        self._clear_votes()

    def _clear_votes(self) -> None:
        votes = self._votes
        for k in range(self.n_classes):
            votes[k] = 0

    def update(self, label: int, scores: np.ndarray | None = None) -> int:
        """One frame's decision (``scores``: that frame's score per class); the class to report, or -1."""
        if label == self.dormant:
            self.dormant_run += 1
            if self.dormant_run > self.gap_frames:
                self._break_run()
            if self.dormant_run >= self.rearm_frames:
                self.armed = True
                self.last_reported = -1
            return -1
        self.dormant_run = 0
        if self.min_margin > 0.0:
            self.margin = margin_of(scores, label)
            if self.margin < self.min_margin:
                self._break_run()
                return -1
        if self.vote:
            votes = self._votes
            votes[label] += 1
            self.run += 1
            if self.candidate < 0 or votes[label] >= votes[self.candidate]:
                self.candidate = label
            label = self.candidate
        elif label == self.candidate:
            self.run += 1
        else:
            self.candidate, self.run = label, 1
        if self.run != self.confirm_frames or not self.armed or label == self.last_reported:
            return -1
        self.last_reported = label
        if self.rearm_frames > 0:
            self.armed = False
        return label

    def _break_run(self) -> None:
        if self.run:
            self.candidate, self.run = -1, 0
            if self.vote:
                self._clear_votes()


def margin_of(scores: np.ndarray | None, label: int) -> float:
    """Score of ``label`` minus the best other score (no allocation: the row is restored in place)."""
    if scores is None:
        raise ValueError("min_margin > 0 needs the scores of each frame")
    top = float(scores[label])
    scores[label] = -np.inf
    second = float(scores.max())
    scores[label] = top
    return top - second
