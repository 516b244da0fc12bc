"""DSACON32m codec: the reference's example bytes, CRC, every packet type both ways, frames."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_io.layout import MatrixInfo, SensorLayout
from firmware_io.wire.crc import CRC_INIT, CRC_TABLE, crc16
from firmware_io.wire.device_time import TimestampUnwrapper
from firmware_io.wire.errors import (
    ChecksumError,
    DeviceError,
    DSAError,
    DSAErrorCode,
    FrameDecodeError,
    ProtocolError,
    RawLengthError,
    RLECountError,
    RLETooLongError,
)
from firmware_io.wire.frames import (
    decode_frame_payload,
    encode_frame,
    encode_frame_payload,
    max_frame_payload,
    rle_units,
)
from firmware_io.wire.packets import PacketId, check_reply, decode_packet, encode_ack, encode_packet
from firmware_io.wire.replies import (
    ControllerInfo,
    MatrixInfoReply,
    MatrixMaskReply,
    SensitivityReply,
    SensorInfo,
    ThresholdReply,
)
from firmware_io.wire.requests import (
    AcquisitionConfig,
    SetSensitivityRequest,
    SetThresholdRequest,
    get_sensitivity_request,
    get_threshold_request,
    push_request,
    query_controller_info_request,
    query_matrix_info_request,
    query_sensor_info_request,
    read_matrix_mask_request,
    single_frame_request,
    stop_request,
)

# The requests SDHLibrary-CPP's sdh/dsa.cpp sends, byte for byte.
EXAMPLES = [
    ("query controller info", query_controller_info_request(), "AA AA AA 01 00 00"),
    ("query sensor info", query_sensor_info_request(), "AA AA AA 02 00 00"),
    ("query matrix 0", query_matrix_info_request(0), "AA AA AA 0B 01 00 00 CB FB"),
    ("query matrix 5", query_matrix_info_request(5), "AA AA AA 0B 01 00 05 6E AB"),
    ("stop", stop_request(rle=True), "AA AA AA 03 03 00 01 00 00 2F 6A"),
    ("push start", push_request(rle=True, rate=1), "AA AA AA 03 03 00 81 01 00 7C 5C"),
    ("single frame", single_frame_request(rle=True), "AA AA AA 03 03 00 81 00 00 2F 68"),
    ("push, no RLE", push_request(rle=False, rate=1), "AA AA AA 03 03 00 80 01 00 DE 36"),
    ("get sensitivity m=0", get_sensitivity_request(0), "AA AA AA 12 01 00 00 8F DB"),
    ("get threshold m=0", get_threshold_request(0), "AA AA AA 14 01 00 00 03 C1"),
    ("ack to 0x03", encode_ack(0x03), "AA AA AA 03 02 00 00 00 4B B9"),
]


@pytest.mark.parametrize(("name", "built", "expected"), EXAMPLES, ids=[e[0] for e in EXAMPLES])
def test_reference_example_packets(name: str, built: bytes, expected: str) -> None:
    assert built == bytes.fromhex(expected)
    # and they decode back through the generic packet decoder
    packet = decode_packet(built)
    assert encode_packet(packet.packet_id, packet.payload) == built


def test_crc_check_value() -> None:
    assert crc16(b"123456789") == 0x6EB4


def _crc_loop(data: bytes, crc: int = CRC_INIT) -> int:
    """One byte a step: the definition (the faster paths are checked against it)."""
    table = CRC_TABLE
    for byte in data:
        crc = (crc >> 8) ^ table[(crc ^ byte) & 0xFF]
    return crc


def test_crc_table_is_msb_first_ccitt() -> None:
    assert CRC_TABLE[0] == 0 and CRC_TABLE[1] == 0x1021 and CRC_TABLE[2] == 0x2042


@settings(max_examples=200, deadline=None)
@given(st.binary(min_size=0, max_size=2200))
def test_vectorised_crc_equals_the_byte_loop(data: bytes) -> None:
    assert crc16(data) == _crc_loop(data)


@settings(max_examples=300, deadline=None)
@given(st.binary(min_size=0, max_size=600), st.integers(0, 0xFFFF))
def test_the_two_bytes_a_step_crc_equals_the_byte_loop(data: bytes, start: int) -> None:
    from firmware_io.wire.crc import _crc_words

    assert _crc_words(data, start) == _crc_loop(data, start)


def test_crc_at_the_switch_between_loop_and_vector() -> None:
    from firmware_io.wire.crc import _VECTOR_CRC_MAX, _VECTOR_CRC_MIN

    rng = np.random.default_rng(4)
    for n in (_VECTOR_CRC_MIN - 1, _VECTOR_CRC_MIN, 980, _VECTOR_CRC_MAX, _VECTOR_CRC_MAX + 1):
        data = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        assert crc16(data) == _crc_loop(data)


def test_empty_payload_has_no_crc_and_nonempty_has_one() -> None:
    assert len(encode_packet(0x01, b"")) == 6
    assert len(encode_packet(0x01, b"\x00")) == 9


def test_decode_packet_rejects_bad_crc_and_sizes() -> None:
    good = bytearray(query_matrix_info_request(3))
    good[-1] ^= 0x01
    with pytest.raises(ChecksumError):
        decode_packet(bytes(good))
    with pytest.raises(ProtocolError):
        decode_packet(query_matrix_info_request(3)[:-1])
    with pytest.raises(ProtocolError):
        decode_packet(b"\xaa\xab\xaa\x01\x00\x00")


# -- replies both ways ----------------------------------------------------------------------------
def test_controller_info_is_18_bytes_and_19_is_accepted() -> None:
    info = ControllerInfo(serial_no=123456, hw_version=2, sw_version=0x2900, can_baudrate=1000000, can_id=0x1234)
    short = info.encode()
    assert len(short) == 18
    decoded = ControllerInfo.decode(short)
    assert decoded.can_id == 0x34  # only the low byte is on the wire
    assert decoded.serial_no == 123456 and decoded.can_baudrate == 1000000
    full = info.encode(full=True)
    assert len(full) == 19
    assert ControllerInfo.decode(full) == info
    for size in (17, 20):
        with pytest.raises(ProtocolError, match="expected 18 or 19"):
            ControllerInfo.decode((full + b"\x00")[:size])


def test_controller_firmware_versions() -> None:
    assert ControllerInfo(sw_version=288).firmware == "R288"
    assert ControllerInfo(sw_version=0x2900).firmware == "2.9.0.0"
    assert ControllerInfo(sw_version=288).single_frame_broken
    assert ControllerInfo(sw_version=268).single_frame_broken
    assert not ControllerInfo(sw_version=269).single_frame_broken
    assert not ControllerInfo(sw_version=289).single_frame_broken
    assert not ControllerInfo(sw_version=0x2900).single_frame_broken


def test_sensor_info_round_trip() -> None:
    info = SensorInfo(nb_matrices=6, generated_by=105, hw_revision=1, serial_no=77, feature_flags=3)
    payload = info.encode()
    assert len(payload) == 12
    assert SensorInfo.decode(payload) == info
    assert decode_packet(info.to_packet()).payload == payload


def test_matrix_info_round_trip_and_layout() -> None:
    reply = MatrixInfoReply(
        texel_width=3.5,
        texel_height=3.25,
        cells_x=6,
        cells_y=13,
        uid=b"abcdef",
        hw_revision=1,
        center=(-50.0, 32.0, 0.5),
        theta=(0.0, 0.25, -1.0),
        fullscale=4095.0,
        feature_flags=2,
    )
    payload = reply.encode()
    assert len(payload) == 52
    assert struct.unpack_from("<HH", payload, 10) == (6, 13)
    assert MatrixInfoReply.decode(payload) == reply
    m = reply.to_matrix_info(3)
    assert isinstance(m, MatrixInfo)
    assert (m.index, m.cells_x, m.cells_y, m.center, m.texel_width) == (3, 6, 13, (-50.0, 32.0, 0.5), 3.5)


def test_matrix_info_from_layout_rebuilds_the_layout() -> None:
    layout = SensorLayout.sdh2()
    replies = [MatrixInfoReply.decode(MatrixInfoReply.from_matrix_info(m).encode()) for m in layout.matrices]
    rebuilt = SensorLayout.from_matrix_infos(r.to_matrix_info(i) for i, r in enumerate(replies))
    assert rebuilt.n_taxels == 486
    assert [(m.cells_x, m.cells_y) for m in rebuilt.matrices] == [(m.cells_x, m.cells_y) for m in layout.matrices]


def test_matrix_without_cells_is_a_protocol_error() -> None:
    with pytest.raises(ProtocolError, match="0x0"):
        MatrixInfoReply(cells_x=0, cells_y=0).to_matrix_info(0)


def test_sensitivity_threshold_and_mask_replies() -> None:
    s = SensitivityReply(adj_flags=2, cur_sens=0.5, fact_sens=0.75)
    assert len(s.encode()) == 11 and SensitivityReply.decode(s.encode()) == s
    t = ThresholdReply(threshold=150)
    assert len(t.encode()) == 4 and ThresholdReply.decode(t.encode()) == t
    mask = SensorLayout.sdh2().matrices[1].mask
    reply = MatrixMaskReply.from_mask(mask)
    assert len(reply.bits) == 10  # ceil(78 / 8)
    back = MatrixMaskReply.decode(reply.encode()).to_mask(6, 13)
    np.testing.assert_array_equal(back, mask)
    with pytest.raises(ProtocolError):
        MatrixMaskReply.decode(b"\x00\x00")


def test_requests_round_trip() -> None:
    cfg = AcquisitionConfig.decode(decode_packet(push_request(rle=False, rate=30)).payload)
    assert (cfg.enabled, cfg.rle, cfg.rate, cfg.mode) == (True, False, 30, "push")
    assert AcquisitionConfig.decode(decode_packet(stop_request()).payload).mode == "stop"
    assert AcquisitionConfig.decode(decode_packet(single_frame_request()).payload).mode == "single"
    sens = SetSensitivityRequest(2, 0.5, persistent=True, all_matrices=True)
    assert SetSensitivityRequest.decode(decode_packet(sens.to_packet()).payload) == sens
    thr = SetThresholdRequest(4, 4095, factory_reset=True)
    assert SetThresholdRequest.decode(decode_packet(thr.to_packet()).payload) == thr
    assert decode_packet(read_matrix_mask_request(1, dynamic=True)).payload == b"\x01\x01"
    with pytest.raises(ValueError):
        SetThresholdRequest(0, 5000).encode()
    with pytest.raises(ValueError):
        push_request(rate=0)


@pytest.mark.parametrize(
    "cls", [ControllerInfo, SensorInfo, MatrixInfoReply, SensitivityReply, ThresholdReply, MatrixMaskReply]
)
def test_error_replies_raise_device_error(cls: type) -> None:
    with pytest.raises(DeviceError) as err:
        cls.decode(struct.pack("<H", DSAErrorCode.NO_SENSOR))
    assert err.value.code == DSAErrorCode.NO_SENSOR
    assert "E_NO_SENSOR" in str(err.value)


def test_check_reply() -> None:
    check_reply(b"\x00\x00")
    with pytest.raises(DeviceError, match=r"E_CMD_UNKNOWN \(13\) to command 0x03"):
        check_reply(b"\x0d\x00", 0x03)
    with pytest.raises(DeviceError, match="UNKNOWN"):
        check_reply(b"\xff\x00")
    with pytest.raises(ProtocolError):
        check_reply(b"\x00")


# -- full frames ---------------------------------------------------------------------------------
N_CELLS = 486


def test_all_zero_rle_frame_is_79_bytes_and_raw_is_985() -> None:
    zeros = np.zeros(N_CELLS, np.uint16)
    assert len(encode_frame(zeros, 0, rle=True)) == 79
    assert len(encode_frame(zeros, 0, rle=False)) == 985


def test_rle_units_carry_any_value_and_split_long_runs() -> None:
    values = np.array([7] * 31 + [0, 4095], np.uint16)
    units = rle_units(values)
    assert [(u & 0xFFF, u >> 12) for u in units.tolist()] == [(7, 15), (7, 15), (7, 1), (0, 1), (4095, 1)]


frame_values = st.lists(
    st.one_of(st.just(0), st.integers(0, 4095), st.just(0xAAA)), min_size=1, max_size=600
).map(lambda v: np.array(v, np.uint16))


@settings(max_examples=150, deadline=None)
@given(frame_values, st.integers(0, 2**32 - 1), st.booleans())
def test_frames_round_trip(values: np.ndarray, timestamp: int, rle: bool) -> None:
    packet = decode_packet(encode_frame(values, timestamp, rle))
    assert packet.packet_id == PacketId.FULL_FRAME
    assert len(packet.payload) <= max_frame_payload(values.size)  # RLE is never longer than raw
    ts, out = decode_frame_payload(packet.payload, values.size)
    assert ts == timestamp
    assert out.dtype == np.uint16
    np.testing.assert_array_equal(out, values)


def test_raw_frames_keep_16_bit_values_and_rle_refuses_them() -> None:
    values = np.array([0, 0xFFFF, 4096], np.uint16)
    _, out = decode_frame_payload(encode_frame_payload(values, 1, rle=False), 3)
    np.testing.assert_array_equal(out, values)
    with pytest.raises(ValueError):
        encode_frame_payload(values, 1, rle=True)


def test_encoding_follows_the_frame_flag_not_the_request() -> None:
    values = np.arange(10, dtype=np.uint16)
    raw = encode_frame_payload(values, 5, rle=False, flags=0x40)
    assert raw[4] == 0x40  # other flag bits are kept and ignored on decode
    np.testing.assert_array_equal(decode_frame_payload(raw, 10)[1], values)


def test_timestamp_wraps_modulo_2_32_on_encode() -> None:
    payload = encode_frame_payload(np.zeros(3, np.uint16), 2**32 + 5, rle=True)
    assert decode_frame_payload(payload, 3)[0] == 5


def test_decode_errors_are_named() -> None:
    values = np.arange(20, dtype=np.uint16)
    raw = encode_frame_payload(values, 0, rle=False)
    with pytest.raises(RawLengthError):
        decode_frame_payload(raw[:-2], 20)
    with pytest.raises(RawLengthError):
        decode_frame_payload(raw, 21)
    rle = encode_frame_payload(np.repeat(np.arange(5, dtype=np.uint16), 4), 0, rle=True)
    assert len(rle) == 5 + 2 * 5
    with pytest.raises(RLECountError):
        decode_frame_payload(rle, 21)
    with pytest.raises(RLECountError):
        decode_frame_payload(rle[:-2], 20)
    with pytest.raises(RLECountError):
        decode_frame_payload(rle + b"\x00", 20)
    # 21 units of count 1 for 20 cells is longer than raw: refused before counting
    too_long = rle[:5] + struct.pack("<21H", *([0x1000] * 21))
    with pytest.raises(RLETooLongError):
        decode_frame_payload(too_long, 20)
    with pytest.raises(FrameDecodeError):
        decode_frame_payload(b"\x00\x00", 20)
    assert issubclass(RLETooLongError, ProtocolError) and issubclass(ProtocolError, DSAError)


def test_zero_count_units_are_legal_padding() -> None:
    payload = struct.pack("<IB", 1, 1) + struct.pack("<3H", 0x0005, 0x3007, 0x0009)
    _, out = decode_frame_payload(payload, 3)
    np.testing.assert_array_equal(out, [7, 7, 7])


# -- device time ---------------------------------------------------------------------------------
def test_timestamp_unwrap_across_2_32() -> None:
    unwrap = TimestampUnwrapper()
    raw = [2**32 - 64, 2**32 - 32, 0, 32, 64]
    out = [unwrap(r) for r in raw]
    assert out == [2**32 - 64, 2**32 - 32, 2**32, 2**32 + 32, 2**32 + 64]
    assert unwrap(2**32 - 10) == 2**32 - 10  # a small step back stays a small step back
    assert unwrap(5) == 2**32 + 5


def test_timestamp_unwrap_over_several_wraps() -> None:
    unwrap = TimestampUnwrapper()
    step = 2**30
    true = [i * step for i in range(20)]
    assert [unwrap(t % 2**32) for t in true] == true
