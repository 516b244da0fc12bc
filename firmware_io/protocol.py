"""DSACON32m wire protocol: packet framing, CRC, request/reply payloads and full frames.

Facts from ``../shared/reference/dsacon32m-protocol.md``. A packet is
``AA AA AA | id | len u16 LE | payload | CRC16 LE``; the CRC is present only when
``len > 0`` and covers id, length and payload (not the preamble). Every field is
little-endian. Both directions are encoded and decoded here: the client decodes
replies, the emulator encodes them, so both stay consistent with one codec.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from firmware_io.layout import MatrixInfo

PREAMBLE = b"\xaa\xaa\xaa"
HEADER_SIZE = 6  # preamble + id + length
CRC_SIZE = 2
FRAME_HEADER_SIZE = 5  # timestamp u32 + flags u8
MAX_TEXEL_VALUE = 0x0FFF
RLE_FLAG = 0x01
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


# -- exceptions ---------------------------------------------------------------------------------
class DSAError(Exception):
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


# -- CRC ----------------------------------------------------------------------------------------
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
_VECTOR_CRC_MIN = 96  # below this a Python loop is cheaper than NumPy's call overhead
_VECTOR_CRC_MAX = 2048  # positions with a precomputed contribution table (4 MiB would be 8192)
_crc_contrib: np.ndarray | None = None
_crc_init_term: np.ndarray | None = None


def _crc_loop(data: bytes, crc: int = CRC_INIT) -> int:
    table = CRC_TABLE
    for byte in data:
        crc = (crc >> 8) ^ table[(crc ^ byte) & 0xFF]
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
        return _crc_loop(data)
    contrib, init = _build_crc_tables()
    values = np.frombuffer(data, dtype=np.uint8)
    terms = contrib[np.arange(n - 1, -1, -1), values]
    return int(np.bitwise_xor.reduce(terms)) ^ int(init[n])


# -- packets ------------------------------------------------------------------------------------
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


# -- requests -----------------------------------------------------------------------------------
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
        _expect_size(payload, 3, "acquisition config (0x03)")
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


def matrix_index_of(payload: bytes, what: str) -> int:
    """The matrix index of a 1-byte request payload (0x0B, 0x12, 0x14), for the emulator."""
    _expect_size(payload, 1, what)
    return payload[0]


@dataclass(frozen=True)
class SetSensitivityRequest:
    """Payload of 0x0F. With ``persistent`` the firmware sends no reply at all."""

    matrix: int
    sensitivity: float
    persistent: bool = False
    all_matrices: bool = False
    factory_reset: bool = False

    def encode(self) -> bytes:
        if not 0.0 <= self.sensitivity <= 1.0:
            raise ValueError(f"sensitivity {self.sensitivity} outside 0..1")
        return struct.pack("<BBf", _set_flags(self), self.matrix, self.sensitivity)

    def to_packet(self) -> bytes:
        return encode_packet(PacketId.ADJUST_MATRIX_SENSITIVITY, self.encode())

    @classmethod
    def decode(cls, payload: bytes) -> SetSensitivityRequest:
        _expect_size(payload, 6, "set sensitivity (0x0F)")
        flags, matrix, value = struct.unpack("<BBf", payload)
        return cls(matrix, value, *_unpack_set_flags(flags))


@dataclass(frozen=True)
class SetThresholdRequest:
    """Payload of 0x13 (threshold 0..4095). With ``persistent`` the firmware sends no reply."""

    matrix: int
    threshold: int
    persistent: bool = False
    all_matrices: bool = False
    factory_reset: bool = False

    def encode(self) -> bytes:
        if not 0 <= self.threshold <= MAX_TEXEL_VALUE:
            raise ValueError(f"threshold {self.threshold} outside 0..4095")
        return struct.pack("<BBH", _set_flags(self), self.matrix, self.threshold)

    def to_packet(self) -> bytes:
        return encode_packet(PacketId.SET_MATRIX_THRESHOLD, self.encode())

    @classmethod
    def decode(cls, payload: bytes) -> SetThresholdRequest:
        _expect_size(payload, 4, "set threshold (0x13)")
        flags, matrix, value = struct.unpack("<BBH", payload)
        return cls(matrix, value, *_unpack_set_flags(flags))


def _set_flags(req: SetSensitivityRequest | SetThresholdRequest) -> int:
    return (
        (FLAG_PERSISTENT if req.persistent else 0)
        | (FLAG_ALL_MATRICES if req.all_matrices else 0)
        | (FLAG_FACTORY_RESET if req.factory_reset else 0)
    )


def _unpack_set_flags(flags: int) -> tuple[bool, bool, bool]:
    return bool(flags & FLAG_PERSISTENT), bool(flags & FLAG_ALL_MATRICES), bool(flags & FLAG_FACTORY_RESET)


# -- replies ------------------------------------------------------------------------------------
def _expect_size(payload: bytes, sizes: int | tuple[int, ...], what: str) -> None:
    ok = (sizes,) if isinstance(sizes, int) else sizes
    if len(payload) not in ok:
        want = " or ".join(str(s) for s in ok)
        raise ProtocolError(f"{what}: payload of {len(payload)} bytes, expected {want}")


def _reply_prologue(payload: bytes, packet_id: int, sizes: int | tuple[int, ...], what: str) -> None:
    """Check the error code first (an error reply is only 2 bytes), then the size."""
    check_reply(payload, packet_id)
    _expect_size(payload, sizes, what)


@dataclass(frozen=True)
class ControllerInfo:
    """Reply to 0x01. The controller sends 18 bytes (only can_id's low byte); 19 is accepted too."""

    serial_no: int = 0
    hw_version: int = 0
    sw_version: int = 0x2900
    status_flags: int = 0
    feature_flags: int = 0
    senscon_type: int = 0
    active_interface: int = 0
    can_baudrate: int = 0
    can_id: int = 0
    error_code: int = 0

    PACKET_ID = PacketId.QUERY_CONTROLLER_CONFIGURATION
    _FORMAT = "<HIBHBBBBIH"  # 19 bytes

    def encode(self, full: bool = False) -> bytes:
        """18 bytes like the real controller; ``full=True`` gives the 19-byte struct."""
        data = struct.pack(
            self._FORMAT,
            self.error_code,
            self.serial_no,
            self.hw_version,
            self.sw_version,
            self.status_flags,
            self.feature_flags,
            self.senscon_type,
            self.active_interface,
            self.can_baudrate,
            self.can_id,
        )
        return data if full else data[:18]

    def to_packet(self, full: bool = False) -> bytes:
        return encode_packet(self.PACKET_ID, self.encode(full))

    @classmethod
    def decode(cls, payload: bytes) -> ControllerInfo:
        _reply_prologue(payload, cls.PACKET_ID, (18, 19), "controller info (0x01)")
        data = bytes(payload) + (b"\x00" if len(payload) == 18 else b"")
        fields = struct.unpack(cls._FORMAT, data)
        return cls(*fields[1:], error_code=fields[0])

    @property
    def firmware(self) -> str:
        """``R288`` for old plain release numbers, ``2.9.0.0`` for nibble-coded versions (>= 0x1000)."""
        v = self.sw_version
        if v < 0x1000:
            return f"R{v}"
        return ".".join(str((v >> s) & 0xF) for s in (12, 8, 4, 0))

    @property
    def single_frame_broken(self) -> bool:
        """Firmware <= R288 (except R269) starts pushing when asked for one frame."""
        v = self.sw_version
        return v < 0x1000 and v <= 288 and v != 269


@dataclass(frozen=True)
class SensorInfo:
    """Reply to 0x02 (12 bytes)."""

    nb_matrices: int = 6
    generated_by: int = 105
    hw_revision: int = 1
    serial_no: int = 0
    feature_flags: int = 0
    error_code: int = 0

    PACKET_ID = PacketId.QUERY_SENSOR_CONFIGURATION
    _FORMAT = "<HHHBIB"

    def encode(self) -> bytes:
        return struct.pack(
            self._FORMAT,
            self.error_code,
            self.nb_matrices,
            self.generated_by,
            self.hw_revision,
            self.serial_no,
            self.feature_flags,
        )

    def to_packet(self) -> bytes:
        return encode_packet(self.PACKET_ID, self.encode())

    @classmethod
    def decode(cls, payload: bytes) -> SensorInfo:
        _reply_prologue(payload, cls.PACKET_ID, 12, "sensor info (0x02)")
        code, nb, gen, hw, serial, feat = struct.unpack(cls._FORMAT, payload)
        return cls(nb, gen, hw, serial, feat, error_code=code)


@dataclass(frozen=True)
class MatrixInfoReply:
    """Reply to 0x0B (52 bytes): one pad's geometry."""

    texel_width: float = 3.4
    texel_height: float = 3.4
    cells_x: int = 6
    cells_y: int = 14
    uid: bytes = b"\x00" * 6
    hw_revision: int = 1
    center: tuple[float, float, float] = (0.0, 0.0, 0.0)
    theta: tuple[float, float, float] = (0.0, 0.0, 0.0)
    fullscale: float = 4095.0
    feature_flags: int = 0
    error_code: int = 0

    PACKET_ID = PacketId.QUERY_MATRIX_CONFIGURATION
    _FORMAT = "<HffHH6s2sBfffffffB"  # 52 bytes

    def encode(self) -> bytes:
        if len(self.uid) != 6:
            raise ValueError("uid must be 6 bytes")
        return struct.pack(
            self._FORMAT,
            self.error_code,
            self.texel_width,
            self.texel_height,
            self.cells_x,
            self.cells_y,
            bytes(self.uid),
            b"\x00\x00",
            self.hw_revision,
            *self.center,
            *self.theta,
            self.fullscale,
            self.feature_flags,
        )

    def to_packet(self) -> bytes:
        return encode_packet(self.PACKET_ID, self.encode())

    @classmethod
    def decode(cls, payload: bytes) -> MatrixInfoReply:
        _reply_prologue(payload, cls.PACKET_ID, 52, "matrix info (0x0B)")
        f = struct.unpack(cls._FORMAT, payload)
        return cls(
            texel_width=f[1],
            texel_height=f[2],
            cells_x=f[3],
            cells_y=f[4],
            uid=f[5],
            hw_revision=f[7],
            center=(f[8], f[9], f[10]),
            theta=(f[11], f[12], f[13]),
            fullscale=f[14],
            feature_flags=f[15],
            error_code=f[0],
        )

    @property
    def sensitivity_adjustable(self) -> bool:
        return bool(self.feature_flags & 0x02)

    def to_matrix_info(self, index: int, static_mask: np.ndarray | None = None) -> MatrixInfo:
        """The layout's view of this pad. Raises ProtocolError for a pad with no cells."""
        if self.cells_x <= 0 or self.cells_y <= 0:
            raise ProtocolError(f"matrix {index}: controller reports {self.cells_x}x{self.cells_y} cells")
        return MatrixInfo(
            index=index,
            cells_x=self.cells_x,
            cells_y=self.cells_y,
            texel_width=float(self.texel_width),
            texel_height=float(self.texel_height),
            center=tuple(float(c) for c in self.center),
            fullscale=float(self.fullscale),
            static_mask=static_mask,
        )

    @classmethod
    def from_matrix_info(cls, info: MatrixInfo, **kw) -> MatrixInfoReply:
        """What a controller with this pad would send (for the emulator)."""
        return cls(
            texel_width=info.texel_width,
            texel_height=info.texel_height,
            cells_x=info.cells_x,
            cells_y=info.cells_y,
            center=tuple(info.center),
            fullscale=info.fullscale,
            **kw,
        )


@dataclass(frozen=True)
class SensitivityReply:
    """Reply to 0x12 (11 bytes). Correct only from firmware R268 on."""

    adj_flags: int = 0x02
    cur_sens: float = 0.5
    fact_sens: float = 0.5
    error_code: int = 0

    PACKET_ID = PacketId.GET_SENSITIVITY_ADJUSTMENT_INFO
    _FORMAT = "<HBff"

    @property
    def adjustable(self) -> bool:
        return bool(self.adj_flags & 0x02)

    def encode(self) -> bytes:
        return struct.pack(self._FORMAT, self.error_code, self.adj_flags, self.cur_sens, self.fact_sens)

    def to_packet(self) -> bytes:
        return encode_packet(self.PACKET_ID, self.encode())

    @classmethod
    def decode(cls, payload: bytes) -> SensitivityReply:
        _reply_prologue(payload, cls.PACKET_ID, 11, "sensitivity (0x12)")
        code, flags, cur, fact = struct.unpack(cls._FORMAT, payload)
        return cls(flags, cur, fact, error_code=code)


@dataclass(frozen=True)
class ThresholdReply:
    """Reply to 0x14 (4 bytes)."""

    threshold: int = 0
    error_code: int = 0

    PACKET_ID = PacketId.GET_MATRIX_THRESHOLD
    _FORMAT = "<HH"

    def encode(self) -> bytes:
        return struct.pack(self._FORMAT, self.error_code, self.threshold)

    def to_packet(self) -> bytes:
        return encode_packet(self.PACKET_ID, self.encode())

    @classmethod
    def decode(cls, payload: bytes) -> ThresholdReply:
        _reply_prologue(payload, cls.PACKET_ID, 4, "threshold (0x14)")
        code, value = struct.unpack(cls._FORMAT, payload)
        return cls(value, error_code=code)


@dataclass(frozen=True)
class MatrixMaskReply:
    """Reply to 0x04: one bit per cell, cell index y*cells_x + x, bit (i % 8) of byte (i // 8)."""

    bits: bytes
    error_code: int = 0

    PACKET_ID = PacketId.READ_MATRIX_MASK

    def encode(self) -> bytes:
        return struct.pack("<H", self.error_code) + bytes(self.bits)

    def to_packet(self) -> bytes:
        return encode_packet(self.PACKET_ID, self.encode())

    @classmethod
    def decode(cls, payload: bytes) -> MatrixMaskReply:
        check_reply(payload, cls.PACKET_ID)
        if len(payload) <= 2:
            raise ProtocolError("matrix mask (0x04): reply carries no mask bits")
        return cls(bytes(payload[2:]))

    def to_mask(self, cells_x: int, cells_y: int) -> np.ndarray:
        n = cells_x * cells_y
        if len(self.bits) * 8 < n:
            raise ProtocolError(f"matrix mask (0x04): {len(self.bits)} bytes cannot hold {n} cells")
        flat = np.unpackbits(np.frombuffer(self.bits, dtype=np.uint8), bitorder="little")[:n]
        return flat.astype(bool).reshape(cells_y, cells_x)

    @classmethod
    def from_mask(cls, mask: np.ndarray) -> MatrixMaskReply:
        return cls(np.packbits(np.asarray(mask, dtype=bool).ravel(), bitorder="little").tobytes())


# -- full frames --------------------------------------------------------------------------------
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
    counts = units >> 12
    total = int(counts.sum())
    if total != n_cells:
        raise RLECountError(f"RLE frame expands to {total} cells, expected {n_cells}")
    return timestamp, np.repeat((units & MAX_TEXEL_VALUE).astype(np.uint16), counts)


# -- device time --------------------------------------------------------------------------------
class TimestampUnwrapper:
    """Turns the device's wrapping u32 millisecond counter into a monotonic int.

    Each step is taken modulo 2**32 and read as signed, so a wrap (after ~49.7 days) adds
    2**32 and a small step backwards (reordering, a reset) stays small instead of jumping.
    """

    WRAP = 1 << 32

    def __init__(self) -> None:
        self._last_raw: int | None = None
        self._value = 0

    def reset(self) -> None:
        self._last_raw = None
        self._value = 0

    def __call__(self, raw: int) -> int:
        raw = int(raw) & 0xFFFFFFFF
        if self._last_raw is None:
            self._value = raw
        else:
            step = (raw - self._last_raw) % self.WRAP
            if step >= self.WRAP // 2:
                step -= self.WRAP
            self._value += step
        self._last_raw = raw
        return self._value
