"""DSACON32m packet framing: ids, preamble, length, CRC, and the error code every reply starts with.

Facts from SCHUNK's SDHLibrary-CPP (``sdh/dsa.cpp``, ``sdh/dsa.h``). A packet is
``AA AA AA | id | len u16 LE | payload | CRC16 LE``; the CRC is present only when
``len > 0`` and covers id, length and payload (not the preamble). Every field is
little-endian. Both directions are encoded and decoded in this package: the client decodes
replies, the emulator encodes them, so both stay consistent with one codec."""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from enum import IntEnum

from firmware_io.wire.crc import crc16
from firmware_io.wire.errors import ChecksumError, DeviceError, DSAErrorCode, ProtocolError

__all__ = [
    "BOOT_TERMINAL_QUERY", "CRC_SIZE", "HEADER_SIZE", "PREAMBLE", "Packet", "PacketId", "check_reply",
    "decode_packet", "encode_ack", "encode_packet", "error_code_of", "expect_size"
]

PREAMBLE = b"\xaa\xaa\xaa"
HEADER_SIZE = 6  # preamble + id + length
CRC_SIZE = 2
BOOT_TERMINAL_QUERY = b"\x1b[5n"
"""ESC[5n: sent three times by the controller about 7 s after power-up."""


class PacketId(IntEnum):
    FULL_FRAME = 0x00
    QUERY_CONTROLLER_CONFIGURATION = 0x01
    QUERY_SENSOR_CONFIGURATION = 0x02
    CONFIGURE_DATA_ACQUISITION = 0x03
    READ_MATRIX_MASK = 0x04
    READ_DESCRIPTOR_STRING = 0x05
    LOOP = 0x06
    QUERY_CONTROLLER_STATE = 0x0A
    QUERY_MATRIX_CONFIGURATION = 0x0B
    SET_PROPERTIES_SAMPLE_RATE = 0x0C
    SET_CONTROL_VECTOR_FOR_MATRIX = 0x0D
    GET_CONTROL_VECTOR_OF_MATRIX = 0x0E
    ADJUST_MATRIX_SENSITIVITY = 0x0F
    QUERY_CONTROLLER_FEATURES = 0x10
    GET_SENSITIVITY_ADJUSTMENT_INFO = 0x12
    SET_MATRIX_THRESHOLD = 0x13
    GET_MATRIX_THRESHOLD = 0x14
    SET_DYNAMIC_MASK = 0xAB


@dataclass(frozen=True, slots=True)
class Packet:
    """One packet as found on the wire. ``received``: perf_counter() when its last byte was parsed."""

    packet_id: int
    payload: bytes
    received: float = field(default=0.0, compare=False)


def encode_packet(packet_id: int, payload: bytes = b"") -> bytes:
    """Frame a payload: preamble, id, length, payload and (only for a non-empty payload) CRC."""
    if not 0 <= packet_id <= 0xFF:
        raise ValueError(f"packet id {packet_id} does not fit in a byte")
    if len(payload) > 0xFFFF:
        raise ValueError(f"payload of {len(payload)} bytes is longer than 65535")
    head = struct.pack("<BH", packet_id, len(payload))
    if not payload:
        return PREAMBLE + head
    body = head + bytes(payload)
    return PREAMBLE + body + struct.pack("<H", crc16(body))


def decode_packet(data: bytes) -> Packet:
    """Decode exactly one complete packet (for tests and tools; streams go through StreamParser)."""
    if len(data) < HEADER_SIZE or data[:3] != PREAMBLE:
        raise ProtocolError("packet does not start with the AA AA AA preamble")
    packet_id, length = struct.unpack_from("<BH", data, 3)
    expected = HEADER_SIZE + length + (CRC_SIZE if length else 0)
    if len(data) != expected:
        raise ProtocolError(f"packet 0x{packet_id:02X} is {len(data)} bytes, its header says {expected}")
    payload = bytes(data[HEADER_SIZE : HEADER_SIZE + length])
    if length:
        (got,) = struct.unpack_from("<H", data, HEADER_SIZE + length)
        want = crc16(data[3 : HEADER_SIZE + length])
        if got != want:
            raise ChecksumError(f"packet 0x{packet_id:02X}: CRC 0x{got:04X}, computed 0x{want:04X}")
    return Packet(packet_id, payload)


def error_code_of(payload: bytes) -> int:
    """The leading u16 error code of a reply payload."""
    if len(payload) < 2:
        raise ProtocolError(f"reply of {len(payload)} bytes has no error code")
    return payload[0] | (payload[1] << 8)


def check_reply(payload: bytes, packet_id: int | None = None) -> None:
    """Raise DeviceError when a reply carries a non-zero error code (every reply, not only some)."""
    code = error_code_of(payload)
    if code != DSAErrorCode.SUCCESS:
        raise DeviceError(code, packet_id)


def encode_ack(packet_id: int, error_code: int = DSAErrorCode.SUCCESS) -> bytes:
    """A 2-byte error-code reply packet (the answer to 0x03, 0x0F, 0x13 and any failed command)."""
    return encode_packet(packet_id, struct.pack("<H", int(error_code)))


def expect_size(payload: bytes, sizes: int | tuple[int, ...], what: str) -> None:
    """One ProtocolError naming the payload when its size is none of ``sizes``."""
    ok = (sizes,) if isinstance(sizes, int) else sizes
    if len(payload) not in ok:
        want = " or ".join(str(s) for s in ok)
        raise ProtocolError(f"{what}: payload of {len(payload)} bytes, expected {want}")
