"""Host -> controller: the request packets and the payloads of the commands that carry settings."""

from __future__ import annotations

import struct
from dataclasses import astuple, dataclass

from firmware_io.wire.frames import MAX_TEXEL_VALUE, RLE_FLAG
from firmware_io.wire.packets import PacketId, encode_packet, expect_size

__all__ = [
    "AcquisitionConfig", "SetSensitivityRequest", "SetThresholdRequest", "get_sensitivity_request",
    "get_threshold_request", "push_request", "query_controller_info_request", "query_matrix_info_request",
    "query_sensor_info_request", "read_matrix_mask_request", "single_frame_request", "stop_request"
]

ACQ_ENABLE = 0x80
FLAG_PERSISTENT = 0x80
FLAG_ALL_MATRICES = 0x02
FLAG_FACTORY_RESET = 0x01


@dataclass(frozen=True)
class AcquisitionConfig:
    """Payload of 0x03: flags (bit7 acquire, bit0 RLE) and a frame rate (0 = stop/single)."""

    flags: int
    rate: int = 0

    @property
    def enabled(self) -> bool:
        return bool(self.flags & ACQ_ENABLE)

    @property
    def rle(self) -> bool:
        return bool(self.flags & RLE_FLAG)

    @property
    def mode(self) -> str:
        """``stop``, ``single`` or ``push`` as the controller interprets the request."""
        if not self.enabled:
            return "stop"
        return "push" if self.rate > 0 else "single"

    def encode(self) -> bytes:
        return struct.pack("<BH", self.flags, self.rate)

    @classmethod
    def decode(cls, payload: bytes) -> AcquisitionConfig:
        expect_size(payload, 3, "acquisition config (0x03)")
        flags, rate = struct.unpack("<BH", payload)
        return cls(flags, rate)


def _acq_flags(enable: bool, rle: bool) -> int:
    return (ACQ_ENABLE if enable else 0) | (RLE_FLAG if rle else 0)


def stop_request(rle: bool = True) -> bytes:
    return encode_packet(PacketId.CONFIGURE_DATA_ACQUISITION, AcquisitionConfig(_acq_flags(False, rle), 0).encode())


def push_request(rle: bool = True, rate: int = 1) -> bytes:
    """Start push mode. ``rate`` > 0 means "as fast as possible" (about 30 fps); it is not a rate."""
    if rate <= 0:
        raise ValueError("push mode needs rate > 0 (rate 0 asks for a single frame)")
    return encode_packet(PacketId.CONFIGURE_DATA_ACQUISITION, AcquisitionConfig(_acq_flags(True, rle), rate).encode())


def single_frame_request(rle: bool = True) -> bytes:
    return encode_packet(PacketId.CONFIGURE_DATA_ACQUISITION, AcquisitionConfig(_acq_flags(True, rle), 0).encode())


def query_controller_info_request() -> bytes:
    return encode_packet(PacketId.QUERY_CONTROLLER_CONFIGURATION)


def query_sensor_info_request() -> bytes:
    return encode_packet(PacketId.QUERY_SENSOR_CONFIGURATION)


def _matrix_byte(matrix: int) -> bytes:
    if not 0 <= matrix <= 0xFF:
        raise ValueError(f"matrix index {matrix} does not fit in a byte")
    return bytes([matrix])


def query_matrix_info_request(matrix: int) -> bytes:
    return encode_packet(PacketId.QUERY_MATRIX_CONFIGURATION, _matrix_byte(matrix))


def get_sensitivity_request(matrix: int) -> bytes:
    return encode_packet(PacketId.GET_SENSITIVITY_ADJUSTMENT_INFO, _matrix_byte(matrix))


def get_threshold_request(matrix: int) -> bytes:
    return encode_packet(PacketId.GET_MATRIX_THRESHOLD, _matrix_byte(matrix))


def read_matrix_mask_request(matrix: int, dynamic: bool = False) -> bytes:
    return encode_packet(PacketId.READ_MATRIX_MASK, bytes([1 if dynamic else 0]) + _matrix_byte(matrix))


class _SetRequest:
    """0x0F and 0x13: flags (persistent, all matrices, factory reset), matrix, value (``_FORMAT``).
    With ``persistent`` the firmware sends no reply at all."""

    PACKET_ID: int
    _FORMAT: str
    _WHAT: str
    _HIGH: float

    def encode(self) -> bytes:
        value = astuple(self)[1]
        if not 0 <= value <= self._HIGH:
            raise ValueError(f"{self._WHAT} {value} outside 0..{self._HIGH:g}")
        flags = ((FLAG_PERSISTENT if self.persistent else 0) | (FLAG_ALL_MATRICES if self.all_matrices else 0)
                 | (FLAG_FACTORY_RESET if self.factory_reset else 0))
        return struct.pack(self._FORMAT, flags, self.matrix, value)

    def to_packet(self) -> bytes:
        return encode_packet(self.PACKET_ID, self.encode())

    @classmethod
    def decode(cls, payload: bytes):
        expect_size(payload, struct.calcsize(cls._FORMAT), f"set {cls._WHAT} (0x{cls.PACKET_ID:02X})")
        flags, matrix, value = struct.unpack(cls._FORMAT, payload)
        return cls(matrix, value, bool(flags & FLAG_PERSISTENT), bool(flags & FLAG_ALL_MATRICES),
                   bool(flags & FLAG_FACTORY_RESET))


@dataclass(frozen=True)
class SetSensitivityRequest(_SetRequest):
    """Payload of 0x0F (sensitivity 0..1)."""

    matrix: int
    sensitivity: float
    persistent: bool = False
    all_matrices: bool = False
    factory_reset: bool = False

    PACKET_ID = PacketId.ADJUST_MATRIX_SENSITIVITY
    _FORMAT, _WHAT, _HIGH = "<BBf", "sensitivity", 1.0


@dataclass(frozen=True)
class SetThresholdRequest(_SetRequest):
    """Payload of 0x13 (threshold 0..4095)."""

    matrix: int
    threshold: int
    persistent: bool = False
    all_matrices: bool = False
    factory_reset: bool = False

    PACKET_ID = PacketId.SET_MATRIX_THRESHOLD
    _FORMAT, _WHAT, _HIGH = "<BBH", "threshold", MAX_TEXEL_VALUE
