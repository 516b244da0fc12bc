"""The options of a command that plays frames through an emulated controller (``handover emulate``,
``handover demo``): ``--speed`` and ``--fault``, read one way with one message each."""

from __future__ import annotations

from firmware_io.emulator.device import FaultPlan, FaultSpecError
from firmware_io.transports.base import TransportError, parse_speed

__all__ = ["playback_options"]


def playback_options(speed: str, fault: str) -> tuple[float | None, FaultPlan]:
    """The playback speed (None: as fast as read) and the fault plan; ValueError with the line to print."""
    try:
        factor = parse_speed("--speed", speed)
    except TransportError:
        raise ValueError(f"--speed {speed!r}: use a positive factor such as 1.0 or 'max'") from None
    try:
        return factor, FaultPlan.parse(fault)
    except FaultSpecError as exc:
        raise ValueError(f"--fault: {exc}") from None
