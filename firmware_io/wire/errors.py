"""What the DSACON32m protocol layer raises, and the controller's own error codes."""

from __future__ import annotations

from enum import IntEnum

from firmware_io.errors import DeviceFailure

__all__ = [
    "ChecksumError", "DSAError", "DSAErrorCode", "DeviceError", "FrameDecodeError", "ProtocolError",
    "RLECountError", "RLETooLongError", "RawLengthError"
]


class DSAErrorCode(IntEnum):
    SUCCESS = 0
    NOT_AVAILABLE = 1
    NO_SENSOR = 2
    NOT_INITIALIZED = 3
    ALREADY_RUNNING = 4
    FEATURE_NOT_SUPPORTED = 5
    INCONSISTENT_DATA = 6
    TIMEOUT = 7
    READ_ERROR = 8
    WRITE_ERROR = 9
    INSUFFICIENT_RESOURCES = 10
    CHECKSUM_ERROR = 11
    CMD_NOT_ENOUGH_PARAMS = 12
    CMD_UNKNOWN = 13
    CMD_FORMAT_ERROR = 14
    ACCESS_DENIED = 15
    ALREADY_OPEN = 16
    CMD_FAILED = 17
    CMD_ABORTED = 18
    INVALID_HANDLE = 19
    DEVICE_NOT_FOUND = 20
    DEVICE_NOT_OPENED = 21
    IO_ERROR = 22
    INVALID_PARAMETER = 23
    INDEX_OUT_OF_BOUNDS = 24
    CMD_PENDING = 25
    OVERRUN = 26
    RANGE_ERROR = 27


class DSAError(DeviceFailure):
    """Base of everything the DSACON32m protocol layer raises."""


class ProtocolError(DSAError):
    """Bytes that do not form a valid packet or payload."""


class ChecksumError(ProtocolError):
    """A packet whose CRC16 does not match its contents."""


class FrameDecodeError(ProtocolError):
    """A full-frame payload that cannot be turned into taxel values."""


class RawLengthError(FrameDecodeError):
    """A raw frame whose payload is not exactly 5 + 2 * n_cells bytes."""


class RLECountError(FrameDecodeError):
    """An RLE frame whose run counts do not add up to the number of cells."""


class RLETooLongError(FrameDecodeError):
    """An RLE frame longer than the raw frame would be: impossible for a real encoder."""


class DeviceError(DSAError):
    """The controller answered with a non-zero error code."""

    def __init__(self, code: int, packet_id: int | None = None) -> None:
        self.code = int(code)
        self.packet_id = packet_id
        try:
            name = DSAErrorCode(self.code).name
        except ValueError:
            name = "UNKNOWN"
        where = "" if packet_id is None else f" to command 0x{packet_id:02X}"
        super().__init__(f"controller replied E_{name} ({self.code}){where}")
