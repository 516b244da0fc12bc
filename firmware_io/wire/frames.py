"""Full frames (packet 0x00): a 5-byte header and the taxel values, raw or run-length encoded."""

from __future__ import annotations

import struct

import numpy as np

from firmware_io.wire.errors import FrameDecodeError, RawLengthError, RLECountError, RLETooLongError
from firmware_io.wire.packets import PacketId, encode_packet

__all__ = [
    "FRAME_HEADER_SIZE", "MAX_TEXEL_VALUE", "RLE_FLAG", "decode_frame_payload", "encode_frame",
    "encode_frame_payload", "max_frame_payload", "rle_units"
]

FRAME_HEADER_SIZE = 5  # timestamp u32 + flags u8
MAX_TEXEL_VALUE = 0x0FFF
RLE_FLAG = 0x01


def max_frame_payload(n_cells: int) -> int:
    """The longest valid full-frame payload: a raw frame (an RLE frame is never longer)."""
    return FRAME_HEADER_SIZE + 2 * n_cells


def rle_units(values: np.ndarray) -> np.ndarray:
    """RLE units (value | count << 12, count 1..15) of 12-bit values, computed without a Python loop."""
    v = np.asarray(values, dtype=np.uint16).ravel()
    if v.size == 0:
        return np.empty(0, dtype=np.uint16)
    if int(v.max()) > MAX_TEXEL_VALUE:
        raise ValueError(f"RLE carries 12-bit values; got {int(v.max())}")
    starts = np.flatnonzero(np.concatenate(([True], v[1:] != v[:-1])))
    lengths = np.diff(np.append(starts, v.size))
    units_per_run = (lengths + 14) // 15
    unit_values = np.repeat(v[starts], units_per_run)
    counts = np.full(unit_values.size, 15, dtype=np.uint16)
    last = np.cumsum(units_per_run) - 1
    counts[last] = lengths - 15 * (units_per_run - 1)
    return (unit_values | (counts << 12)).astype(np.uint16)


def encode_frame_payload(values: np.ndarray, timestamp_ms: int, rle: bool, flags: int = 0) -> bytes:
    """Payload of a full frame. The timestamp is taken modulo 2**32 (the device counter wraps)."""
    v = np.asarray(values)
    if v.ndim != 1:
        raise ValueError(f"a frame is one row of taxel values, got shape {v.shape}")
    if v.size and (int(v.min()) < 0 or int(v.max()) > 0xFFFF):
        raise ValueError("taxel values must fit in u16")
    flag_byte = (flags & ~RLE_FLAG & 0xFF) | (RLE_FLAG if rle else 0)
    head = struct.pack("<IB", int(timestamp_ms) & 0xFFFFFFFF, flag_byte)
    body = rle_units(v) if rle else v.astype(np.uint16)
    return head + body.astype("<u2").tobytes()


def encode_frame(values: np.ndarray, timestamp_ms: int, rle: bool, flags: int = 0) -> bytes:
    """A whole full-frame packet (id 0x00), raw or RLE."""
    return encode_packet(PacketId.FULL_FRAME, encode_frame_payload(values, timestamp_ms, rle, flags))


def decode_frame_payload(payload: bytes, n_cells: int) -> tuple[int, np.ndarray]:
    """``(timestamp u32, values uint16 [n_cells])`` from a full-frame payload, raw or RLE by flag bit 0."""
    size = len(payload)
    if size < FRAME_HEADER_SIZE:
        raise FrameDecodeError(f"full frame of {size} bytes is shorter than its 5-byte header")
    timestamp = payload[0] | (payload[1] << 8) | (payload[2] << 16) | (payload[3] << 24)
    rle = payload[4] & RLE_FLAG
    data_size = size - FRAME_HEADER_SIZE
    if not rle:
        if data_size != 2 * n_cells:
            raise RawLengthError(
                f"raw frame carries {data_size} data bytes, {n_cells} cells need {2 * n_cells}"
            )
        return timestamp, np.frombuffer(payload, dtype="<u2", offset=FRAME_HEADER_SIZE).astype(np.uint16)
    if data_size > 2 * n_cells:
        raise RLETooLongError(f"RLE frame of {data_size} data bytes is longer than a raw frame ({2 * n_cells})")
    if data_size % 2:
        raise RLECountError(f"RLE frame has an odd number of data bytes ({data_size})")
    units = np.frombuffer(payload, dtype="<u2", offset=FRAME_HEADER_SIZE)
    # expanded before the count is checked (at most 15 cells a unit, so bounded): one NumPy call
    # less than summing the counts first, which a frame arriving on cold caches pays for
    values = np.repeat((units & MAX_TEXEL_VALUE).astype(np.uint16, copy=False), units >> 12)
    if values.size != n_cells:
        raise RLECountError(f"RLE frame expands to {values.size} cells, expected {n_cells}")
    return timestamp, values
