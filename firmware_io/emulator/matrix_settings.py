"""The emulated controller's per-matrix threshold and sensitivity, and what they do to a frame.

A write lasts until the next power cycle; a persistent one becomes the new factory default (``dsa.h``).
How the firmware applies them is not published: the emulator's model is in docs/EMULATOR.md.
"""

from __future__ import annotations

import numpy as np

from firmware_io.layout import SensorLayout
from firmware_io.wire import replies
from firmware_io.wire.errors import DSAErrorCode
from firmware_io.wire.frames import MAX_TEXEL_VALUE
from firmware_io.wire.packets import encode_ack
from firmware_io.wire.requests import SetSensitivityRequest, SetThresholdRequest

__all__ = ["MatrixSettings"]

FACTORY_SENSITIVITY = 0.5
"""The sensitivity a controller leaves the factory with, and the one recordings are taken at."""


class MatrixSettings:
    """Current and stored (persistent) threshold and sensitivity of each matrix."""

    def __init__(self, layout: SensorLayout) -> None:
        self.layout = layout
        n = layout.n_matrices
        self.stored_thresholds = [0] * n
        self.stored_sensitivity = [FACTORY_SENSITIVITY] * n
        self.thresholds = [0] * n
        self.sensitivity = [FACTORY_SENSITIVITY] * n

    def power_on(self) -> None:
        """What a power cycle leaves: the stored values."""
        self.thresholds = list(self.stored_thresholds)
        self.sensitivity = list(self.stored_sensitivity)

    def apply(self, values: np.ndarray) -> np.ndarray:
        """The frame as the controller reports it under the current settings (unchanged at the factory's)."""
        if not any(self.thresholds) and all(s == FACTORY_SENSITIVITY for s in self.sensitivity):
            return values
        out = values.astype(np.float64)
        for m in range(self.layout.n_matrices):
            cells = self.layout.matrix_slice(m)
            pad = np.minimum(np.rint(out[cells] * (self.sensitivity[m] / FACTORY_SENSITIVITY)), MAX_TEXEL_VALUE)
            pad[pad < self.thresholds[m]] = 0
            out[cells] = pad
        return out.astype(values.dtype)

    def set_sensitivity(self, req: SetSensitivityRequest) -> bytes:
        """Reply to 0x0F (none to a persistent write, as the firmware sends none)."""
        in_range = req.factory_reset or 0.0 <= req.sensitivity <= 1.0
        return self._write(req, in_range, float(req.sensitivity), self.sensitivity, self.stored_sensitivity)

    def set_threshold(self, req: SetThresholdRequest) -> bytes:
        """Reply to 0x13 (none to a persistent write)."""
        in_range = req.threshold <= MAX_TEXEL_VALUE
        return self._write(req, in_range, int(req.threshold), self.thresholds, self.stored_thresholds)

    def _write(self, req: SetSensitivityRequest | SetThresholdRequest, in_range: bool, value: float,
               current: list, stored: list) -> bytes:
        error = DSAErrorCode.SUCCESS
        if not req.all_matrices and req.matrix >= self.layout.n_matrices:
            error = DSAErrorCode.INDEX_OUT_OF_BOUNDS
        elif not in_range:
            error = DSAErrorCode.RANGE_ERROR
        else:
            for m in self._targets(req.all_matrices, req.matrix):
                current[m] = stored[m] if req.factory_reset else value
                if req.persistent:
                    stored[m] = current[m]
        return b"" if req.persistent else encode_ack(req.PACKET_ID, error)

    def sensitivity_reply(self, m: int) -> bytes:
        return replies.SensitivityReply(0x02, self.sensitivity[m], self.stored_sensitivity[m]).to_packet()

    def threshold_reply(self, m: int) -> bytes:
        return replies.ThresholdReply(self.thresholds[m]).to_packet()

    def _targets(self, all_matrices: bool, matrix: int) -> range | list[int]:
        return range(self.layout.n_matrices) if all_matrices else [matrix]
