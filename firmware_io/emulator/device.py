"""An emulated DSACON32m: host bytes in, device bytes out, with optional faults.

``DeviceEmulator`` has no threads and no sockets: a link feeds it what the host wrote and asks for the
bytes due now. The same core sits behind ``sim://``/``replay://``, the TCP and pseudo-terminal servers
and the pyusb/hidapi test doubles, so a client sees one device whichever way it connects. Where it
behaves like the real controller (clock, session, line rate, power cycle, settings): docs/EMULATOR.md.
Commands it does not know get E_CMD_UNKNOWN; host packets with a bad CRC are dropped silently.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from firmware_io.emulator.faults import FaultPlan, FaultSpecError, inject
from firmware_io.emulator.identity import recorded_controller, recorded_sensor
from firmware_io.emulator.matrix_settings import MatrixSettings
from firmware_io.frame_timing import NOMINAL_PERIOD_S
from firmware_io.recordings.recording import Recording
from firmware_io.wire import replies
from firmware_io.wire.errors import DSAErrorCode, ProtocolError
from firmware_io.wire.frames import MAX_TEXEL_VALUE, encode_frame
from firmware_io.wire.packets import BOOT_TERMINAL_QUERY, PacketId, encode_ack
from firmware_io.wire.parser import StreamParser
from firmware_io.wire.requests import AcquisitionConfig, SetSensitivityRequest, SetThresholdRequest

__all__ = ["DeviceEmulator", "FaultPlan", "FaultSpecError"]

MAX_COMMAND_PAYLOAD = 64
BOOT_S = 8.0
"""A power-cycled DSACON32m answers again after about this long."""
BOOT_QUERY_S = 7.0
"""... and sends its terminal query ESC[5n about this long after power-on ..."""
BOOT_QUERY_REPEATS = (0.0, 0.41, 0.82)
"""... three times within 0.82 s (SDHLibrary-Python ``dsa.py``, ``cDSA.__init__``)."""
LINE_BURST_S = 0.005
"""Bytes a paced line may owe and then send at once (a UART's FIFO, a scheduler's slice)."""


class HostCommandParser(StreamParser):
    """The stream parser with the host's view: any command id is plausible, so an unknown one
    reaches the emulator and gets E_CMD_UNKNOWN instead of being dropped as line noise."""

    def plausible(self, packet_id: int, length: int) -> bool:
        return length <= MAX_COMMAND_PAYLOAD


@dataclass
class EmulatorStats:
    """What the emulator did; tests compare these with what the client counted."""

    commands: int = 0
    unknown_commands: int = 0
    frames_sent: int = 0
    crc_corrupted: int = 0
    garbage_inserted: int = 0
    garbage_bytes: int = 0
    packets_truncated: int = 0
    bytes_dropped: int = 0
    stalls: int = 0
    disconnects: int = 0
    power_cycles: int = 0
    frames_skipped: int = 0
    boot_queries: int = 0
    connections: int = 0
    by_command: dict[int, int] = field(default_factory=dict)

    def as_dict(self) -> dict:
        d = dict(self.__dict__)
        d["by_command"] = {f"0x{k:02X}": v for k, v in sorted(self.by_command.items())}
        return d


class DeviceEmulator:
    """The controller's behaviour as a pure byte machine driven by ``feed`` and ``read``."""

    def __init__(
        self,
        recording: Recording,
        *,
        speed: float | None = 1.0,
        loop: bool = True,
        old_firmware: bool = False,
        faults: FaultPlan | None = None,
        seed: int = 0,
        start_ms: int = 0,
        serial_no: int | None = None,
        clock: Callable[[], float] = time.monotonic,
        boot_s: float = BOOT_S,
        boot_query_s: float = BOOT_QUERY_S,
        session_starts: str = "power_on",
    ) -> None:
        if recording.n_frames == 0:
            raise ValueError("the emulator needs a recording with at least one frame")
        if speed is not None and speed <= 0:
            raise ValueError(f"speed must be positive or None (as fast as possible), got {speed}")
        self.recording = recording
        self.layout = recording.layout
        self.speed = speed
        self.loop = loop
        self.old_firmware = old_firmware
        self.faults = faults or FaultPlan()
        self.start_ms = int(start_ms)
        self.clock = clock
        if not 0 <= boot_query_s <= boot_s:
            raise ValueError(f"boot_query_s must be within 0..boot_s, got {boot_query_s} of {boot_s}")
        self.boot_s, self.boot_query_s = float(boot_s), float(boot_query_s)
        if session_starts not in ("power_on", "first_acquisition"):
            raise ValueError(f"session_starts must be 'power_on' or 'first_acquisition', got {session_starts!r}")
        self._session_waits = session_starts == "first_acquisition"
        """The recording starts when a host first asks for frames (a scripted session played to a host
        that connects later), not at power-on; the clock runs from power-on either way."""
        self.stats = EmulatorStats()
        self._rng = np.random.default_rng(seed)
        self._parser = HostCommandParser()
        self._out = bytearray()
        self.settings = MatrixSettings(self.layout)
        meta = getattr(recording, "meta", None) or {}
        self.controller = recorded_controller(meta, serial_no, old_firmware)
        self.sensor = recorded_sensor(meta, self.layout.n_matrices, self.controller.serial_no)
        rel = recording.timestamps - recording.timestamps[0]
        self._rel_ms = np.round(rel * 1000.0).astype(np.int64)
        self._rel_s = rel
        step = recording.sample_interval()
        self._loop_period = float(rel[-1] + (step if np.isfinite(step) else NOMINAL_PERIOD_S))
        self._next = 0  # frame sequence number across loops
        self._pushing = False
        self._rle = True
        created = self.clock()
        self._origin = created  # wall time at which frame sequence 0 is due (the world started)
        self._power_on = created  # wall time of the last power-on: the device clock's zero
        self._booting_until = 0.0
        self._boot_queries_due: list[float] = []  # when the booting controller sends ESC[5n
        self._line_bps: float | None = None  # bytes per second the line carries; None: unlimited
        self._line_t = created
        self._line_credit = 0.0
        self._stall_until = 0.0
        self._frames_this_connection = 0
        self.disconnected = False
        self._single_at: float | None = None  # when the requested single frame is due
        self._last_single = -1e9

    # -- the link's view ----------------------------------------------------------------------
    def connect(self) -> None:
        """A host attached (TCP accept, pty opened, transport created): maybe send the boot query."""
        self.stats.connections += 1
        self._new_link()
        if self.faults.boot_query:
            self._out += BOOT_TERMINAL_QUERY * 3
            self.stats.boot_queries += 1

    def _new_link(self) -> None:
        self.disconnected = False
        self._frames_this_connection = 0
        self._parser = HostCommandParser()
        self._out.clear()  # bytes in flight on a dropped link are lost
        self._stall_until = 0.0

    def power_cycle(self, now: float | None = None) -> None:
        """What an unplugged and replugged controller does: the bytes in flight are lost, it is
        silent and ignores commands for ``boot_s``, sends ESC[5n three times from ``boot_query_s`` on,
        and comes back with its clock restarted, push mode off and only the persistently stored settings."""
        now = self.clock() if now is None else now
        self._new_link()
        self.stats.power_cycles += 1
        self._pushing = False
        self._single_at = None
        self._power_on = now
        self._booting_until = now + self.boot_s
        first = now + self.boot_query_s
        self._boot_queries_due = [t for t in (first + d for d in BOOT_QUERY_REPEATS) if t <= now + self.boot_s] or [first]
        self.settings.power_on()

    @property
    def booting(self) -> bool:
        return self.clock() < self._booting_until

    def device_ms(self, now: float | None = None) -> int:
        """The device clock: ms since power-on plus ``start_ms`` (device time runs ``speed`` times
        the wall clock), wrapping at 2**32."""
        now = self.clock() if now is None else now
        pace = 1.0 if self.speed is None else self.speed
        return (self.start_ms + round((now - self._power_on) * pace * 1000.0)) % 2**32

    def set_line_rate(self, bytes_per_s: float | None) -> None:
        """The line's capacity (a serial line at B baud, 8N1: B / 10 bytes per second); None: unlimited."""
        self._line_bps = bytes_per_s if bytes_per_s and bytes_per_s > 0 else None

    def _paced(self) -> bool:
        return self._line_bps is not None and self.speed is not None

    def feed(self, data: bytes, now: float | None = None) -> None:
        """Bytes the host wrote: every complete command is answered into the output queue (a
        booting controller hears nothing)."""
        now = self.clock() if now is None else now
        if now < self._booting_until:
            return
        for packet in self._parser.feed(bytes(data)):
            self._handle(packet.packet_id, bytes(packet.payload), now)

    def read(self, max_bytes: int = 4096, now: float | None = None) -> bytes:
        """The device bytes due by ``now`` (at most ``max_bytes``)."""
        now = self.clock() if now is None else now
        if self.disconnected or now < self._stall_until:
            return b""
        while self._boot_queries_due and now >= self._boot_queries_due[0]:
            self._boot_queries_due.pop(0)
            self._out += BOOT_TERMINAL_QUERY
            self.stats.boot_queries += 1
        if now < self._booting_until:
            return self._take(max_bytes, now)
        self._produce(now, max_bytes)
        if now < self._stall_until and not self._out:
            return b""
        return self._take(max_bytes, now)

    def _take(self, max_bytes: int, now: float) -> bytes:
        """Up to ``max_bytes`` of the output queue, no more than the line has carried since."""
        if self._paced():
            burst = max(64.0, self._line_bps * LINE_BURST_S)
            self._line_credit = min(burst, self._line_credit + (now - self._line_t) * self._line_bps)
            self._line_t = now
            max_bytes = min(max_bytes, int(self._line_credit))
        out = bytes(self._out[:max_bytes])
        del self._out[:max_bytes]
        if self._paced():
            self._line_credit -= len(out)
        return out

    def seconds_until_output(self, now: float | None = None) -> float | None:
        """How long until ``read`` would return something; None if nothing is scheduled."""
        now = self.clock() if now is None else now
        if self.disconnected:
            return None
        if now < self._stall_until:
            return self._stall_until - now
        if self._boot_queries_due:
            return max(0.0, self._boot_queries_due[0] - now)
        if self._out:
            if self._paced() and self._line_credit < 1.0:
                return min(LINE_BURST_S, (1.0 - self._line_credit) / self._line_bps)
            return 0.0
        if now < self._booting_until:
            return None
        if self._single_at is not None:
            return max(0.0, self._single_at - now)
        if not self._pushing or self.finished:
            return None
        return max(0.0, self._due(self._next) - now)

    @property
    def finished(self) -> bool:
        """A recording without ``loop`` has sent its last frame and the output is drained."""
        return not self.loop and self._next >= self.recording.n_frames and not self._out

    @property
    def pushing(self) -> bool:
        return self._pushing

    # -- frames -------------------------------------------------------------------------------
    def _due(self, seq: int) -> float:
        if self.speed is None:
            return self._origin
        return self._origin + self._seq_time(seq) / self.speed

    def _seq_time(self, seq: int) -> float:
        loops, i = divmod(seq, self.recording.n_frames)
        return loops * self._loop_period + float(self._rel_s[i])

    def _exhausted(self) -> bool:
        return not self.loop and self._next >= self.recording.n_frames

    def _seq_at(self, t: float) -> int:
        """The frame the sensor sees at wall time ``t``: the newest one due by then (0 before the first)."""
        if self.speed is None:
            return self._next
        elapsed = max(0.0, (t - self._origin) * self.speed)
        loops, within = divmod(elapsed, self._loop_period)
        i = int(np.searchsorted(self._rel_s, within, side="right")) - 1
        return int(loops) * self.recording.n_frames + max(i, 0)

    def _skip_to(self, seq: int) -> None:
        """Frames before ``seq`` went by while nobody asked for them."""
        if seq > self._next:
            self.stats.frames_skipped += seq - self._next
            self._next = seq

    def _produce(self, now: float, budget: int) -> None:
        if self._single_at is not None and now >= self._single_at and now >= self._stall_until:
            self._single_at, self._last_single = None, now
            if self.speed is not None:
                self._skip_to(self._seq_at(now))
            if not self._exhausted():
                self._emit_frame(now)
        while self._pushing and len(self._out) < budget and not self._exhausted():
            if now < self._stall_until or self.disconnected or self._due(self._next) > now:
                return
            if self._paced():
                if self._out:
                    return  # the previous frame is still on the line
                self._skip_to(self._seq_at(now))  # the newest frame, once the line is free
                if self._exhausted():
                    return
            self._emit_frame(now)

    def _emit_frame(self, now: float) -> None:
        seq = self._next
        self._next += 1
        i = seq % self.recording.n_frames
        stamp = self.stamp_of(seq)
        values = self.settings.apply(self.recording.frames[i])
        rle = self._rle and int(values.max(initial=0)) <= MAX_TEXEL_VALUE
        packet = bytearray(encode_frame(values, stamp % 2**32, rle=rle))
        if inject(self.faults, self._rng, self.stats, packet, self._out):
            self._stall_until = now + self.faults.stall_seconds
            self._origin += self.faults.stall_seconds
        self.stats.frames_sent += 1
        self._frames_this_connection += 1
        if self.faults.disconnect_after and self._frames_this_connection >= self.faults.disconnect_after:
            self.disconnected = True
            self.stats.disconnects += 1

    @property
    def session_clock_ms(self) -> int | None:
        """The device clock at the recording's first frame (frame i is stamped this plus its time
        in the recording), or None while the session waits for a host to ask for frames."""
        return None if self._session_waits else self._clock_offset_ms() % 2**32

    def stamp_of(self, seq: int) -> int:
        """The device timestamp frame ``seq`` (counted over loops) carries when sent, before the u32 wrap."""
        loops, i = divmod(seq, self.recording.n_frames)
        return self._clock_offset_ms() + loops * round(self._loop_period * 1000) + int(self._rel_ms[i])

    def _clock_offset_ms(self) -> int:
        """The device clock at the moment the world's frame 0 was due (``start_ms`` until a power cycle
        or a stall shifts one against the other)."""
        if self.speed is None:
            return self.start_ms
        return self.start_ms + round((self._origin - self._power_on) * self.speed * 1000.0)

    # -- commands -----------------------------------------------------------------------------
    def _handle(self, pid: int, payload: bytes, now: float) -> None:
        self.stats.commands += 1
        self.stats.by_command[pid] = self.stats.by_command.get(pid, 0) + 1
        handler = self._HANDLERS.get(pid)
        if handler is None:
            self.stats.unknown_commands += 1
            self._out += encode_ack(pid, DSAErrorCode.CMD_UNKNOWN)
            return
        try:
            reply = handler(self, payload, now)
        except ProtocolError:
            code = DSAErrorCode.CMD_NOT_ENOUGH_PARAMS if len(payload) < _MIN_SIZE.get(pid, 0) else DSAErrorCode.CMD_FORMAT_ERROR
            reply = encode_ack(pid, code)
        if reply:
            self._out += reply

    def _matrix(self, pid: int, payload: bytes) -> int | bytes:
        """Matrix index of a 1-byte request, or the error reply to send."""
        if len(payload) != 1:
            raise ProtocolError("matrix request needs one byte")
        m = payload[0]
        if m >= self.layout.n_matrices:
            return encode_ack(pid, DSAErrorCode.INDEX_OUT_OF_BOUNDS)
        return m

    def _on_controller(self, payload: bytes, now: float) -> bytes:
        return self.controller.to_packet()

    def _on_sensor(self, payload: bytes, now: float) -> bytes:
        return self.sensor.to_packet()

    def _on_matrix_info(self, payload: bytes, now: float) -> bytes:
        m = self._matrix(PacketId.QUERY_MATRIX_CONFIGURATION, payload)
        if isinstance(m, bytes):
            return m
        info = self.layout.matrices[m]
        uid = struct.pack("<IH", self.controller.serial_no, m)
        return replies.MatrixInfoReply.from_matrix_info(info, uid=uid, feature_flags=0x02).to_packet()

    def _on_mask(self, payload: bytes, now: float) -> bytes:
        if len(payload) != 2:
            raise ProtocolError("mask request needs two bytes")
        if payload[1] >= self.layout.n_matrices:
            return encode_ack(PacketId.READ_MATRIX_MASK, DSAErrorCode.INDEX_OUT_OF_BOUNDS)
        return replies.MatrixMaskReply.from_mask(self.layout.matrices[payload[1]].mask).to_packet()

    def _on_acquisition(self, payload: bytes, now: float) -> bytes:
        cfg = AcquisitionConfig.decode(payload)
        self._out += encode_ack(PacketId.CONFIGURE_DATA_ACQUISITION)
        if self._session_waits and cfg.mode != "stop":
            self._session_waits = False
            self._origin = now
        self._rle = cfg.rle
        mode = cfg.mode
        if mode == "single" and self.old_firmware:
            mode = "push"  # firmware <= R288 starts push mode on a single-frame request (its known bug)
        if mode == "stop":
            self._pushing = False
        elif mode == "push":
            if not self._pushing:
                self._pushing = True
                if self.speed is None:
                    self._origin = now
                else:  # the first frame sent is the one the sensor sees now
                    self._skip_to(self._seq_at(now))
        elif not self._exhausted():  # single frame: the next one the sensor acquires, not at once,
            self._pushing = False  # and never one stamped after the moment it is sent
            self._single_at = max(now, self._last_single + self._frame_period(), self._due(self._next))
        return b""

    def _frame_period(self) -> float:
        """Seconds between two acquisitions (0 when serving as fast as possible)."""
        if self.speed is None:
            return 0.0
        step = self.recording.sample_interval()
        return (step if np.isfinite(step) and step > 0 else NOMINAL_PERIOD_S) / self.speed

    def _on_set_sensitivity(self, payload: bytes, now: float) -> bytes:
        return self.settings.set_sensitivity(SetSensitivityRequest.decode(payload))

    def _on_get_sensitivity(self, payload: bytes, now: float) -> bytes:
        m = self._matrix(PacketId.GET_SENSITIVITY_ADJUSTMENT_INFO, payload)
        return m if isinstance(m, bytes) else self.settings.sensitivity_reply(m)

    def _on_set_threshold(self, payload: bytes, now: float) -> bytes:
        return self.settings.set_threshold(SetThresholdRequest.decode(payload))

    def _on_get_threshold(self, payload: bytes, now: float) -> bytes:
        m = self._matrix(PacketId.GET_MATRIX_THRESHOLD, payload)
        return m if isinstance(m, bytes) else self.settings.threshold_reply(m)

    _HANDLERS: ClassVar[dict[int, Callable[[DeviceEmulator, bytes, float], bytes]]] = {
        PacketId.QUERY_CONTROLLER_CONFIGURATION: _on_controller,
        PacketId.QUERY_SENSOR_CONFIGURATION: _on_sensor,
        PacketId.QUERY_MATRIX_CONFIGURATION: _on_matrix_info,
        PacketId.READ_MATRIX_MASK: _on_mask,
        PacketId.CONFIGURE_DATA_ACQUISITION: _on_acquisition,
        PacketId.ADJUST_MATRIX_SENSITIVITY: _on_set_sensitivity,
        PacketId.GET_SENSITIVITY_ADJUSTMENT_INFO: _on_get_sensitivity,
        PacketId.SET_MATRIX_THRESHOLD: _on_set_threshold,
        PacketId.GET_MATRIX_THRESHOLD: _on_get_threshold,
    }


_MIN_SIZE = {
    PacketId.QUERY_MATRIX_CONFIGURATION: 1,
    PacketId.READ_MATRIX_MASK: 2,
    PacketId.CONFIGURE_DATA_ACQUISITION: 3,
    PacketId.ADJUST_MATRIX_SENSITIVITY: 6,
    PacketId.GET_SENSITIVITY_ADJUSTMENT_INFO: 1,
    PacketId.SET_MATRIX_THRESHOLD: 4,
    PacketId.GET_MATRIX_THRESHOLD: 1,
}
