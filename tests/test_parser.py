"""StreamParser: chunking, resynchronisation, boot query, byte accounting, and a bounded fuzz test."""

from __future__ import annotations

import itertools
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from firmware_io.wire.frames import decode_frame_payload, encode_frame
from firmware_io.wire.packets import BOOT_TERMINAL_QUERY, CRC_SIZE, HEADER_SIZE, encode_ack, encode_packet
from firmware_io.wire.parser import StreamParser
from firmware_io.wire.replies import ControllerInfo, MatrixInfoReply, SensorInfo, ThresholdReply
from firmware_io.wire.requests import query_controller_info_request

N_CELLS = 486


def frame_packet(rng: np.random.Generator, rle: bool, ts: int = 0) -> bytes:
    values = np.zeros(N_CELLS, np.uint16)
    k = int(rng.integers(0, 60))
    values[rng.integers(0, N_CELLS, k)] = rng.integers(0, 4096, k)
    return encode_frame(values, ts, rle)


def reply_packet(rng: np.random.Generator) -> bytes:
    choice = int(rng.integers(0, 6))
    return [
        encode_ack(0x03),
        ControllerInfo(serial_no=int(rng.integers(0, 2**31))).to_packet(),
        SensorInfo().to_packet(),
        MatrixInfoReply(cells_y=13).to_packet(),
        ThresholdReply(int(rng.integers(0, 4096))).to_packet(),
        query_controller_info_request(),  # a zero-length packet (no CRC)
    ][choice]


def good_stream(seed: int, n: int) -> list[bytes]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        r = rng.random()
        out.append(frame_packet(rng, rle=r < 0.5, ts=i) if r < 0.7 else reply_packet(rng))
    return out


def _largest_packet(parser: StreamParser) -> int:
    return HEADER_SIZE + parser._max_frame + CRC_SIZE


def parse_all(data: bytes, cuts: list[int] | None = None, n_cells: int | None = N_CELLS) -> tuple[list, StreamParser]:
    parser = StreamParser(n_cells)
    packets = []
    bounds = sorted({0, len(data), *[c for c in (cuts or []) if 0 < c < len(data)]})
    for a, b in itertools.pairwise(bounds):
        packets += parser.feed(data[a:b])
        assert parser.pending <= _largest_packet(parser)  # bounded memory
    packets += parser.flush_pending()
    return [encode_packet(p.packet_id, p.payload) for p in packets], parser


# -- behaviour --------------------------------------------------------------------------------------
def test_clean_stream_all_packets_and_accounting() -> None:
    pkts = good_stream(1, 40)
    data = b"".join(pkts)
    out, parser = parse_all(data)
    assert out == pkts
    s = parser.stats
    assert (s.bytes_dropped, s.packets_dropped, s.crc_errors, s.bad_headers) == (0, 0, 0, 0)
    assert s.packets == 40 and s.packet_bytes == len(data) == s.bytes_in


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10_000), st.lists(st.integers(0, 20_000), max_size=40))
def test_any_chunking_gives_the_same_packets(seed: int, cuts: list[int]) -> None:
    pkts = good_stream(seed, 12)
    data = b"".join(pkts)
    out, _ = parse_all(data, [c % (len(data) + 1) for c in cuts])
    assert out == pkts


def test_byte_by_byte() -> None:
    pkts = good_stream(2, 10)
    data = b"".join(pkts)
    out, _ = parse_all(data, list(range(len(data))))
    assert out == pkts


def test_garbage_between_packets_is_counted() -> None:
    pkts = good_stream(3, 6)
    junk = [b"hello", b"\x00\xff" * 7, b"\xaa\xaa", b"\xaa", b"\x1b[5"]
    data = b"".join(p + j for p, j in zip(pkts, [*junk, b""], strict=True))
    out, parser = parse_all(data)
    assert out == pkts
    assert parser.stats.bytes_dropped == sum(map(len, junk))


def test_flipped_crc_byte_drops_one_packet_only() -> None:
    pkts = good_stream(4, 8)
    bad = bytearray(pkts[3])
    bad[-1] ^= 0x40
    data = b"".join(pkts[:3]) + bytes(bad) + b"".join(pkts[4:])
    out, parser = parse_all(data)
    assert out == pkts[:3] + pkts[4:]
    assert parser.stats.crc_errors == 1 and parser.stats.packets_dropped == 1
    assert parser.stats.bytes_dropped == len(bad)


def test_bad_length_too_long_is_rejected_at_once() -> None:
    pkts = good_stream(5, 6)
    bad = bytearray(pkts[2])
    bad[4:6] = struct.pack("<H", 60000)  # implausible: no waiting for 60 kB
    data = b"".join(pkts[:2]) + bytes(bad) + b"".join(pkts[3:])
    parser = StreamParser(N_CELLS)
    out = parser.feed(data)
    assert [encode_packet(p.packet_id, p.payload) for p in out] == pkts[:2] + pkts[3:]
    assert parser.stats.bad_headers >= 1


def test_plausible_but_wrong_length_recovers_following_packets() -> None:
    pkts = good_stream(6, 10)
    bad = bytearray(pkts[2])
    bad[4:6] = struct.pack("<H", 2)  # shorter than the real packet: CRC fails, rescan from +1
    data = b"".join(pkts[:2]) + bytes(bad) + b"".join(pkts[3:])
    out, _ = parse_all(data)
    assert out == pkts[:2] + pkts[3:]


def test_wrong_length_waiting_at_the_end_is_released_by_flush() -> None:
    """A corrupt length that asks for more than ever comes: the reply behind it is found on flush."""
    ack = encode_ack(0x03)
    bad = bytearray(ThresholdReply(7).to_packet())
    bad[4:6] = struct.pack("<H", 40)
    parser = StreamParser(N_CELLS)
    assert parser.feed(bytes(bad) + ack) == []
    out = parser.flush_pending()
    assert [(p.packet_id, p.payload) for p in out] == [(0x03, b"\x00\x00")]


def test_stray_aa_before_a_preamble() -> None:
    pkts = good_stream(7, 6)
    for run in (1, 2, 5, 17):
        data = pkts[0] + b"\xaa" * run + b"".join(pkts[1:])
        out, parser = parse_all(data)
        assert out == pkts, run
        assert parser.stats.bytes_dropped == run


def test_aaaa_inside_payloads_and_a_damaged_frame_hiding_a_fake_header() -> None:
    # RLE units 0xAAAA (value 2730 x 10) twice give AA AA AA AA inside the payload, followed by
    # bytes that read as a plausible frame header (id 0, length 0x0051 = 81).
    units = [0xAAAA, 0xAAAA, 0x5100] + [0xF000] * 30 + [0xB007]
    assert sum(u >> 12 for u in units) == N_CELLS
    payload = struct.pack("<IB", 9, 1) + struct.pack(f"<{len(units)}H", *units)
    tricky = encode_packet(0, payload)
    assert b"\xaa\xaa\xaa\xaa\x00\x51\x00" in tricky[6:]
    assert StreamParser(N_CELLS).plausible(0x00, 0x51)
    _, values = decode_frame_payload(payload, N_CELLS)
    assert values[:20].tolist() == [2730] * 20
    pkts = good_stream(8, 5)
    out, _ = parse_all(pkts[0] + tricky + pkts[1] + b"".join(pkts[2:]))
    assert out == [pkts[0], tricky, *pkts[1:]]
    damaged = bytearray(tricky)
    damaged[-2] ^= 0xFF
    out, parser = parse_all(pkts[0] + bytes(damaged) + b"".join(pkts[1:]))
    assert out == pkts
    assert parser.stats.crc_errors >= 1


def test_boot_query_is_skipped_not_dropped() -> None:
    pkts = good_stream(9, 4)
    boot = BOOT_TERMINAL_QUERY
    data = boot + boot + pkts[0] + boot + b"".join(pkts[1:])
    for cuts in ([], list(range(0, len(data), 3)), list(range(len(data)))):
        out, parser = parse_all(data, cuts)
        assert out == pkts
        assert parser.stats.boot_queries == 3
        assert parser.stats.bytes_dropped == 0


def test_interleaved_replies_and_frames_keep_order() -> None:
    rng = np.random.default_rng(10)
    pkts = []
    for i in range(20):
        pkts.append(frame_packet(rng, rle=True, ts=i))
        if i % 3 == 0:
            pkts.append(MatrixInfoReply(cells_y=14).to_packet())
        if i % 4 == 1:
            pkts.append(encode_ack(0x03))
    out, _ = parse_all(b"".join(pkts), list(range(0, 5000, 97)))
    assert out == pkts


def test_unknown_layout_still_parses_frames() -> None:
    pkts = good_stream(11, 10)
    out, _ = parse_all(b"".join(pkts), n_cells=None)
    assert out == pkts


def test_frame_lengths_checked_against_cells() -> None:
    parser = StreamParser(N_CELLS)
    assert parser.plausible(0, 5 + 2 * N_CELLS)
    assert not parser.plausible(0, 5 + 2 * N_CELLS + 2)
    assert not parser.plausible(0, 6)  # odd number of data bytes
    assert not parser.plausible(0, 5 + 2 * 10)  # an RLE frame needs >= ceil(486/15) units
    assert not parser.plausible(0xAA, 2) and not parser.plausible(0x07, 2)
    assert parser.plausible(0x0B, 52) and not parser.plausible(0x0B, 500)


def test_received_time_is_set() -> None:
    parser = StreamParser()
    (packet,) = parser.feed(encode_ack(3))
    assert packet.received > 0


# -- fuzz -----------------------------------------------------------------------------------------
damage = st.one_of(
    st.binary(min_size=1, max_size=300).map(lambda b: ("garbage", b)),
    st.tuples(st.integers(0, 10**6), st.integers(1, 255)).map(lambda t: ("flip", t)),
    st.tuples(st.integers(0, 10**6), st.integers(1, 200)).map(lambda t: ("cut", t)),
    st.tuples(st.integers(0, 10**6), st.integers(0, 0xFFFF)).map(lambda t: ("length", t)),
    st.integers(1, 8).map(lambda n: ("aa", b"\xaa" * n)),
)


def apply_damage(victim: bytes, kind: str, arg: object) -> bytes:
    """Damage confined to the bytes between the good packets before and after it."""
    if kind in ("garbage", "aa"):
        return victim + arg  # type: ignore[operator]
    pos, val = arg  # type: ignore[misc]
    if not victim:
        return b"\xaa\xaa\xaa" + bytes([val & 0xFF])
    pos %= len(victim)
    if kind == "flip":
        out = bytearray(victim)
        out[pos] ^= val
        return bytes(out)
    if kind == "cut":
        return victim[:pos] + victim[pos + val :]
    out = bytearray(victim)
    if len(out) >= 6:
        out[4:6] = struct.pack("<H", val)
    return bytes(out)


@settings(
    max_examples=300,
    deadline=2000,
    suppress_health_check=[HealthCheck.too_slow],
)
@given(
    st.integers(0, 10**6),
    st.lists(st.tuples(st.integers(0, 30), damage), min_size=1, max_size=4),
    st.lists(st.integers(0, 50_000), max_size=25),
)
def test_fuzz_mutated_streams_recover_the_next_good_packet(seed: int, damages: list, cuts: list[int]) -> None:
    """Each damaged packet (plus injected bytes) is lost at most; every undamaged packet arrives."""
    pkts = good_stream(seed, 30)
    damaged_at = {i % len(pkts): d for i, d in damages}
    pieces, expected = [], []
    for i, pkt in enumerate(pkts):
        if i in damaged_at:
            kind, arg = damaged_at[i]
            pieces.append(apply_damage(pkt, kind, arg))
            if kind in ("garbage", "aa"):
                expected.append(pkt)  # the packet itself is intact; the bytes after it are noise
        else:
            pieces.append(pkt)
            expected.append(pkt)
    data = b"".join(pieces)
    out, parser = parse_all(data, [c % (len(data) + 1) for c in cuts])
    # every intact packet is recovered, in order (an extra packet could only be a forged one
    # with a matching CRC, or a 6-byte zero-length packet spelled by the damage itself)
    it = iter(out)
    assert all(any(o == e for o in it) for e in expected)
    assert len(out) - len(expected) <= sum(1 for k, _ in damaged_at.values() if k in ("garbage", "aa")) + len(
        damaged_at
    )
    s = parser.stats
    assert s.packet_bytes + 4 * s.boot_queries + s.bytes_dropped == s.bytes_in


@settings(max_examples=80, deadline=2000)
@given(st.binary(max_size=6000), st.lists(st.integers(0, 6000), max_size=20))
def test_fuzz_random_bytes_never_crash_and_stay_bounded(data: bytes, cuts: list[int]) -> None:
    parser = StreamParser(N_CELLS)
    tail = encode_ack(0x03)
    _, parser = parse_all(data + tail, cuts)
    s = parser.stats
    assert s.packet_bytes + 4 * s.boot_queries + s.bytes_dropped == s.bytes_in
    assert parser.pending == 0


@settings(max_examples=80, deadline=2000)
@given(st.binary(max_size=3000))
def test_fuzz_random_bytes_then_a_good_packet_is_found(noise: bytes) -> None:
    """Whatever precedes it, a good packet after noise comes out (after a flush at most)."""
    good = ThresholdReply(1234).to_packet()
    parser = StreamParser(N_CELLS)
    out = parser.feed(noise + good) + parser.flush_pending()
    assert any(p.packet_id == 0x14 and p.payload == good[6:-2] for p in out)


@pytest.mark.parametrize("n_cells", [None, 10, N_CELLS])
def test_pending_never_exceeds_one_packet(n_cells: int | None) -> None:
    parser = StreamParser(n_cells)
    header = b"\xaa\xaa\xaa\x00" + struct.pack("<H", parser._max_frame)
    parser.feed(header + b"\x00" * (parser._max_frame - 1))
    assert parser.pending <= _largest_packet(parser)
    for _ in range(50):
        parser.feed(b"\x55" * 1000)
        assert parser.pending <= _largest_packet(parser)
