"""Reads frames for a detector, rehearsing the model once just before a frame that will run it.

Why: between frames the hot thread sleeps a whole period, and a decision that follows finds the
graph's code and data cold; the same run once a moment earlier (``Detector.rehearsal_at``) warms
them for the one that counts. It costs one model run per decision and nothing between events;
results/latency.md measures what it buys. The daemon's loop and the latency bench read through it.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from firmware_io.client import Frame
    from runtime.detector import Detector

__all__ = ["RehearsedReads"]


class RehearsedReads:
    """``reads()``: the next frame from ``read(timeout)``, or None after ``timeout`` s (or at a rehearsal)."""

    def __init__(self, read: Callable[[float], Frame | None], detector: Detector, timeout: float,
                 rehearse: bool = True) -> None:
        self.read, self.detector, self.timeout, self.rehearse = read, detector, timeout, rehearse
        self._done: float | None = None
        """``rehearsal_at`` of the last rehearsal: one per frame."""

    def __call__(self) -> Frame | None:
        at = self.detector.rehearsal_at() if self.rehearse else None
        if at is None or at == self._done:
            return self.read(self.timeout)
        frame = self.read(min(self.timeout, max(0.0, at - time.perf_counter())))
        if frame is None and time.perf_counter() >= at:
            self._done = at
            self.detector.rehearse()
        return frame
