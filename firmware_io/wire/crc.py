"""The DSACON32m CRC16 (init 0xFFFF, reflected update with the MSB-first CCITT table), vectorised."""

from __future__ import annotations

import sys
from array import array

import numpy as np

__all__ = ["CRC_TABLE", "crc16"]


def _ccitt_table() -> tuple[int, ...]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


CRC_TABLE = _ccitt_table()
CRC_INIT = 0xFFFF
_CRC_TABLE_NP = np.array(CRC_TABLE, dtype=np.uint16)
_VECTOR_CRC_MIN = 512
"""Below this a Python loop is cheaper than NumPy. Why so high: in service a frame arrives after a
period of idle, when NumPy's call paths and the table are out of the caches, so the loop wins for
frames far longer than back to back; raw frames (replays stream them back to back) keep NumPy, and
run-length-encoded SDH-2 frames (the client's default) stay below this unless most taxels are
pressed. Figures: results/design_figures.md."""
_VECTOR_CRC_MAX = 2048  # positions with a precomputed contribution table (4 MiB would be 8192)
_crc_contrib: np.ndarray | None = None
_crc_init_term: np.ndarray | None = None
_ROW_OF_POSITION = np.arange(_VECTOR_CRC_MAX - 1, -1, -1, dtype=np.intp) * 256
"""Flat index of the contribution row of the byte ``n - 1 - i`` from the end, for ``[-n:]``."""


def _word_table() -> array:
    """Two bytes a step. Two byte steps from ``crc`` over ``b0, b1`` depend only on
    ``x = crc ^ (b0 | b1 << 8)``: ``T[x & 0xFF] >> 8 ^ T[(x >> 8 ^ T[x & 0xFF]) & 0xFF]`` (the first step's
    ``crc >> 8`` only reaches the second step's index byte). 65,536 entries, 128 KiB."""
    t = _CRC_TABLE_NP.astype(np.uint32)
    x = np.arange(1 << 16, dtype=np.uint32)
    first = t[x & 0xFF]
    return array("H", ((first >> 8) ^ t[((x >> 8) ^ first) & 0xFF]).astype(np.uint16).tobytes())


_WORD_TABLE = _word_table()
_LITTLE_ENDIAN = sys.byteorder == "little"


def _crc_words(data: bytes, crc: int = CRC_INIT) -> int:
    """The byte-at-a-time table loop, two bytes a step: half the Python steps."""
    view = memoryview(data)
    if len(view) & 1:
        crc = (crc >> 8) ^ CRC_TABLE[(crc ^ view[0]) & 0xFF]
        view = view[1:]
    words = view.cast("H") if _LITTLE_ENDIAN else np.frombuffer(view, dtype="<u2").tolist()
    table = _WORD_TABLE
    for word in words:
        crc = table[crc ^ word]
    return crc


def _build_crc_tables() -> tuple[np.ndarray, np.ndarray]:
    """Per-position contribution of each byte value, so a CRC is one gather and one XOR-reduce.

    Why: the update is linear over GF(2). With F(c) = (c >> 8) ^ T[c & 0xFF], the CRC of
    bytes b_0..b_{n-1} is F^n(init) ^ XOR_i F^(n-1-i)(T[b_i]). Python loops cost ~60 ns a
    byte; this keeps a 977-byte raw frame's CRC in a few microseconds.
    """
    global _crc_contrib, _crc_init_term
    if _crc_contrib is None:
        contrib = np.empty((_VECTOR_CRC_MAX, 256), dtype=np.uint16)
        init = np.empty(_VECTOR_CRC_MAX + 1, dtype=np.uint16)
        row = _CRC_TABLE_NP.copy()
        c = CRC_INIT
        init[0] = c
        for k in range(_VECTOR_CRC_MAX):
            contrib[k] = row
            row = (row >> 8) ^ _CRC_TABLE_NP[row & 0xFF]
            c = (c >> 8) ^ CRC_TABLE[c & 0xFF]
            init[k + 1] = c
        _crc_contrib, _crc_init_term = contrib, init
    return _crc_contrib, _crc_init_term  # type: ignore[return-value]


def crc16(data: bytes) -> int:
    """DSACON32m CRC16: init 0xFFFF, reflected update with the MSB-first CCITT (0x1021) table."""
    n = len(data)
    if n < _VECTOR_CRC_MIN or n > _VECTOR_CRC_MAX:
        return _crc_words(data)
    contrib, init = _build_crc_tables()
    terms = contrib.ravel().take(_ROW_OF_POSITION[-n:] + np.frombuffer(data, dtype=np.uint8))
    return int(np.bitwise_xor.reduce(terms)) ^ int(init[n])
