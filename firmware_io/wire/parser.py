"""Incremental DSACON32m stream parser: bytes in any chunks -> whole, CRC-checked packets.

The stream can hold garbage, a boot-time terminal query, flipped bits and preamble bytes inside
payloads: headers are checked for plausibility before waiting for a payload, a failure restarts the
search one byte after the failed preamble, memory is bounded to one packet, and every byte ends in a
packet, a boot query or ``bytes_dropped``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from firmware_io.wire.crc import crc16
from firmware_io.wire.frames import FRAME_HEADER_SIZE, max_frame_payload
from firmware_io.wire.packets import BOOT_TERMINAL_QUERY, CRC_SIZE, HEADER_SIZE, PREAMBLE, Packet, PacketId

__all__ = ["Packet", "StreamParser"]

DEFAULT_MAX_CELLS = 1024
"""Cells assumed before the layout is known (the SDH-2 has 486)."""
MAX_REPLY_PAYLOAD = 64
"""Longest command or reply payload other than frames and masks (matrix info: 52)."""
_MASK_IDS = (PacketId.READ_MATRIX_MASK, PacketId.SET_DYNAMIC_MASK)
_KNOWN_IDS = frozenset(int(p) for p in PacketId)
_BOOT_LEN = len(BOOT_TERMINAL_QUERY)


@dataclass
class ParserStats:
    """Counters since the parser was made. Every byte fed is in exactly one of
    ``packet_bytes``, ``boot_queries * 4``, ``bytes_dropped`` or still pending."""

    bytes_in: int = 0
    packets: int = 0
    packet_bytes: int = 0
    bytes_dropped: int = 0
    packets_dropped: int = 0
    crc_errors: int = 0
    bad_headers: int = 0
    boot_queries: int = 0


class StreamParser:
    """Feed bytes, get packets. ``n_cells`` (taxels a frame) tightens the frame-length check."""

    def __init__(self, n_cells: int | None = None) -> None:
        self.stats = ParserStats()
        self._buf = bytearray()
        self.set_cells(n_cells)

    # -- configuration ---------------------------------------------------------------------------
    def set_cells(self, n_cells: int | None) -> None:
        """Set the taxels per frame once the layout is known (None: a generous default)."""
        if n_cells is not None and n_cells <= 0:
            raise ValueError(f"n_cells must be positive, got {n_cells}")
        self.n_cells = n_cells
        cells = n_cells if n_cells is not None else DEFAULT_MAX_CELLS
        self._max_frame = max_frame_payload(cells)
        # The shortest RLE frame: every unit counts 15 cells.
        self._min_frame = FRAME_HEADER_SIZE + (2 * (-(-n_cells // 15)) if n_cells else 0)
        self._max_mask = 3 + -(-cells // 8)

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the rest of a packet (or of a preamble)."""
        return len(self._buf)

    def plausible(self, packet_id: int, length: int) -> bool:
        """Could a packet with this id have this payload length (either direction)?"""
        if packet_id == PacketId.FULL_FRAME:
            return self._min_frame <= length <= self._max_frame and (length - FRAME_HEADER_SIZE) % 2 == 0
        if packet_id not in _KNOWN_IDS:
            return False
        if packet_id in _MASK_IDS:
            return length <= self._max_mask
        return length <= MAX_REPLY_PAYLOAD

    # -- parsing ---------------------------------------------------------------------------------
    def feed(self, data: bytes) -> list[Packet]:
        """Add bytes; return every packet completed by them, in stream order."""
        if data:
            self.stats.bytes_in += len(data)
            self._buf += data
        return self._parse(time.perf_counter(), flush=False)

    def flush_pending(self) -> list[Packet]:
        """The stream went quiet: give up on the packet being waited for and rescan what follows it.

        Why: a corrupt but plausible length makes the parser wait for bytes that may never come
        (a command reply with nothing after it). The caller calls this after a gap timeout.
        Any incomplete tail is dropped.
        """
        out = self._parse(time.perf_counter(), flush=True)
        if self._buf:
            self._drop_garbage(bytes(self._buf))
            self._buf.clear()
        return out

    def reset(self) -> None:
        """Forget pending bytes (after a reconnect), counting them as dropped."""
        if self._buf:
            self._drop_garbage(bytes(self._buf))
            self._buf.clear()

    def _parse(self, now: float, flush: bool) -> list[Packet]:
        buf = self._buf
        stats = self.stats
        out: list[Packet] = []
        pos = 0
        n = len(buf)
        while True:
            idx = buf.find(PREAMBLE, pos)
            if idx < 0:
                keep = _partial_tail(buf, max(pos, n - 3))
                self._drop_garbage(bytes(buf[pos:keep]))
                pos = keep
                break
            if idx > pos:
                self._drop_garbage(bytes(buf[pos:idx]))
                pos = idx
            if n - idx < HEADER_SIZE:
                if flush:
                    # not a packet: drop the first preamble byte and look again
                    stats.bytes_dropped += 1
                    pos = idx + 1
                    continue
                break
            packet_id = buf[idx + 3]
            length = buf[idx + 4] | (buf[idx + 5] << 8)
            if not self.plausible(packet_id, length):
                stats.bad_headers += 1
                stats.bytes_dropped += 1
                pos = idx + 1
                continue
            end = idx + HEADER_SIZE + length + (CRC_SIZE if length else 0)
            if end > n:
                if flush:
                    stats.packets_dropped += 1
                    stats.bytes_dropped += 1
                    pos = idx + 1
                    continue
                break
            if length:
                body_end = idx + HEADER_SIZE + length
                crc = buf[body_end] | (buf[body_end + 1] << 8)
                if crc != crc16(bytes(buf[idx + 3 : body_end])):
                    stats.crc_errors += 1
                    stats.packets_dropped += 1
                    stats.bytes_dropped += 1
                    pos = idx + 1
                    continue
                payload = bytes(buf[idx + HEADER_SIZE : body_end])
            else:
                payload = b""
            out.append(Packet(packet_id, payload, now))
            stats.packets += 1
            stats.packet_bytes += end - idx
            pos = end
        if pos:
            del buf[:pos]
        return out

    def _drop_garbage(self, chunk: bytes) -> None:
        """Count bytes outside packets; boot terminal queries are expected, not dropped."""
        if not chunk:
            return
        queries = chunk.count(BOOT_TERMINAL_QUERY)
        self.stats.boot_queries += queries
        self.stats.bytes_dropped += len(chunk) - queries * _BOOT_LEN


def _partial_tail(buf: bytearray, start: int) -> int:
    """Where the kept tail starts: the last bytes that may begin a preamble or a boot query."""
    n = len(buf)
    for i in range(max(start, n - (_BOOT_LEN - 1)), n):
        tail = bytes(buf[i:])
        if PREAMBLE.startswith(tail) or BOOT_TERMINAL_QUERY.startswith(tail):
            return i
    return n
