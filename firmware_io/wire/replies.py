"""Controller -> host: the replies to the queries, decoded by the client and encoded by the emulator."""

from __future__ import annotations

import struct
from dataclasses import astuple, dataclass

import numpy as np

from firmware_io.layout import MatrixInfo, fullscale_problem
from firmware_io.wire.errors import ProtocolError
from firmware_io.wire.packets import PacketId, check_reply, encode_packet, expect_size

__all__ = ["ControllerInfo", "MatrixInfoReply", "MatrixMaskReply", "SensitivityReply", "SensorInfo", "ThresholdReply",
           "serial_text"]


def serial_text(serial_no: int) -> str:
    """A controller's or sensor's serial number on screen: 8 hex digits, no ``0x`` (``1D9B0057``), as Weiss's
    DSA-Konqueror writes ``<serial_nr>`` in a .dsa file, so a number shown can be found in a recording's header.
    (SDHLibrary prints the field in decimal, but only in a debug dump of the whole struct.)"""
    return f"{serial_no:08X}"


def _reply_prologue(payload: bytes, packet_id: int, sizes: int | tuple[int, ...], what: str) -> None:
    """Check the error code first (an error reply is only 2 bytes), then the size."""
    check_reply(payload, packet_id)
    expect_size(payload, sizes, what)


class _Reply:
    """A reply whose payload is its error code, then its fields in order (``_FORMAT``; the dataclass
    lists ``error_code`` last, as a default)."""

    PACKET_ID: int
    _FORMAT: str

    def encode(self) -> bytes:
        return struct.pack(self._FORMAT, self.error_code, *astuple(self)[:-1])

    def to_packet(self) -> bytes:
        return encode_packet(self.PACKET_ID, self.encode())

    @classmethod
    def _unpack(cls, payload: bytes):
        code, *fields = struct.unpack(cls._FORMAT, payload)
        return cls(*fields, error_code=code)


@dataclass(frozen=True)
class ControllerInfo(_Reply):
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
        data = super().encode()
        return data if full else data[:18]

    def to_packet(self, full: bool = False) -> bytes:
        return encode_packet(self.PACKET_ID, self.encode(full))

    @classmethod
    def decode(cls, payload: bytes) -> ControllerInfo:
        _reply_prologue(payload, cls.PACKET_ID, (18, 19), "controller info (0x01)")
        return cls._unpack(bytes(payload) + (b"\x00" if len(payload) == 18 else b""))

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
class SensorInfo(_Reply):
    """Reply to 0x02 (12 bytes)."""

    nb_matrices: int = 6
    generated_by: int = 105
    hw_revision: int = 1
    serial_no: int = 0
    feature_flags: int = 0
    error_code: int = 0

    PACKET_ID = PacketId.QUERY_SENSOR_CONFIGURATION
    _FORMAT = "<HHHBIB"

    @classmethod
    def decode(cls, payload: bytes) -> SensorInfo:
        _reply_prologue(payload, cls.PACKET_ID, 12, "sensor info (0x02)")
        return cls._unpack(payload)


@dataclass(frozen=True)
class MatrixInfoReply(_Reply):
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

    def to_matrix_info(self, index: int, static_mask: np.ndarray | None = None) -> MatrixInfo:
        """The layout's view of this pad. Raises ProtocolError for a pad with no cells or a full scale
        no 12-bit pad has."""
        if self.cells_x <= 0 or self.cells_y <= 0:
            raise ProtocolError(f"matrix {index}: controller reports {self.cells_x}x{self.cells_y} cells")
        if problem := fullscale_problem(self.fullscale):
            raise ProtocolError(f"matrix {index}: controller reports {problem}")
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
class SensitivityReply(_Reply):
    """Reply to 0x12 (11 bytes). Correct only from firmware R268 on."""

    adj_flags: int = 0x02
    cur_sens: float = 0.5
    fact_sens: float = 0.5
    error_code: int = 0

    PACKET_ID = PacketId.GET_SENSITIVITY_ADJUSTMENT_INFO
    _FORMAT = "<HBff"

    @classmethod
    def decode(cls, payload: bytes) -> SensitivityReply:
        _reply_prologue(payload, cls.PACKET_ID, 11, "sensitivity (0x12)")
        return cls._unpack(payload)


@dataclass(frozen=True)
class ThresholdReply(_Reply):
    """Reply to 0x14 (4 bytes)."""

    threshold: int = 0
    error_code: int = 0

    PACKET_ID = PacketId.GET_MATRIX_THRESHOLD
    _FORMAT = "<HH"

    @classmethod
    def decode(cls, payload: bytes) -> ThresholdReply:
        _reply_prologue(payload, cls.PACKET_ID, 4, "threshold (0x14)")
        return cls._unpack(payload)


@dataclass(frozen=True)
class MatrixMaskReply(_Reply):
    """Reply to 0x04: one bit per cell, cell index y*cells_x + x, bit (i % 8) of byte (i // 8)."""

    bits: bytes
    error_code: int = 0

    PACKET_ID = PacketId.READ_MATRIX_MASK

    def encode(self) -> bytes:
        return struct.pack("<H", self.error_code) + bytes(self.bits)

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
