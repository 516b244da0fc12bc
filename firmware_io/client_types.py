"""What a DSAClient hands out: frames, and the two ways a wait ends without an answer.

Kept apart from the client so the client module stays one job (talking to the controller);
``firmware_io.client`` re-exports all three.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from firmware_io.errors import HandoverError
from firmware_io.wire.errors import DSAError

__all__ = ["Cancelled", "DSATimeout", "Frame"]


class DSATimeout(DSAError):
    """The controller did not answer in time."""


class Cancelled(HandoverError):
    """The caller's ``should_stop`` predicate asked to give up (e.g. SIGTERM while opening).

    Deliberately not a DSAError or TransportError, so no retry loop swallows it."""


@dataclass(frozen=True, slots=True)
class Frame:
    """One full frame. ``number`` counts frames decoded since open (gaps = dropped frames);
    ``timestamp_ms`` is device time unwrapped across the u32 wrap; ``received`` is
    ``time.perf_counter()`` when the packet's last byte was parsed; ``values`` uint16 in wire order."""

    number: int
    timestamp_ms: int
    received: float
    values: np.ndarray
