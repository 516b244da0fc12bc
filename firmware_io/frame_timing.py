"""The SDH-2 controller's nominal frame rate: the one place it is stated.

Whatever must assume a rate before (or without) measuring one takes it from here. Not to be confused
with ``firmware_io.sim.constants.FRAME_PERIOD_S`` (the real recordings' measured mean interval, a
little longer) or a recording's or model's own rate, which wins over both.
"""

from __future__ import annotations

__all__ = ["NOMINAL_PERIOD_S", "NOMINAL_RATE_HZ", "nominal_stamp_ms"]

NOMINAL_RATE_HZ = 32.0
"""Frames per second the controller is configured to stream."""

NOMINAL_PERIOD_S = 1.0 / NOMINAL_RATE_HZ
"""Seconds between frames at the nominal rate."""


def nominal_stamp_ms(number: int) -> int:
    """The controller's millisecond time stamp of frame ``number`` of a stream at the nominal rate,
    for code that makes frames (benchmarks, emulated streams) rather than reading them."""
    return round(number * 1000.0 * NOMINAL_PERIOD_S)
