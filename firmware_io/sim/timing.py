"""PC time stamps of frames: a steady device clock read by a PC that is sometimes late."""

from __future__ import annotations

import numpy as np

from firmware_io.sim import constants as K

__all__ = ["frame_stamps"]


def frame_stamps(n: int, rng: np.random.Generator, start: float = 0.0) -> np.ndarray:
    """``n`` strictly increasing stamps (seconds) with the jitter of the real recordings.

    The frames leave the controller on a steady clock (period ``FRAME_PERIOD_S``); the PC
    stamps each one when it reads it, sometimes a few ms late, then on time again. That is
    why real intervals anti-correlate (a long one followed by a short one) rather than drift.
    Stamps are whole milliseconds, as in the .dsa files.
    """
    k = np.arange(n, dtype=np.float64)
    delay = np.abs(rng.normal(0.0, K.STAMP_BASE_JITTER_S, n))
    late = rng.random(n) < K.STAMP_LATE_PROB
    delay += late * rng.exponential(K.STAMP_LATE_MEAN_S, n)
    very = rng.random(n) < K.STAMP_VERY_LATE_PROB
    delay += very * rng.exponential(K.STAMP_VERY_LATE_MEAN_S, n)
    # a late read never reaches the next frame's read
    delay = np.minimum(delay, 0.5 * K.FRAME_PERIOD_S)
    t = start + k * K.FRAME_PERIOD_S + delay
    t = np.round(t / K.STAMP_RESOLUTION_S) * K.STAMP_RESOLUTION_S
    # delays stay below half a period, so stamps are >= 15 ms apart: strictly increasing
    return t
