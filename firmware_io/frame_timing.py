"""The SDH-2 controller's nominal frame rate: the one place it is stated.

The rate the tactile controller is set to stream at. Whatever must assume a rate before (or
without) measuring one takes it from here: the daemon before a model says its rate, a model file
whose maker did not say, a recording too short to measure, emulated devices and scripted subjects,
benchmarks that pace frames, and a decision's deadline (one period).

Two other quantities look alike and are not this one. The mean interval of the real recordings
(``firmware_io.sim.constants.FRAME_PERIOD_S``) is a measurement, a little longer than the nominal
period because the PC reads some frames late; the simulator writes its recordings at it so that
their intervals look real. A recording's or a model's own rate (``Recording.sample_interval``,
``sample_rate_hz`` in a model's metadata) is what that data says and wins over both.
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
