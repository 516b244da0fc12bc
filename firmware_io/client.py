"""DSACON32m client: open a controller, learn its pads, and read frames from it.

Follows the SDHLibrary ``cDSA`` sequence with the corrections of the protocol reference
(section 7): every retry and wait is bounded, EOF is a disconnect, ``error_code`` is
checked in every reply, unexpected frames are queued rather than lost, and the old-firmware
single-frame bug is handled by stop + drain. Not thread-safe: one thread owns a client.
"""

from __future__ import annotations

import contextlib
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from firmware_io.client_exchange import CommandExchange
from firmware_io.client_recovery import RESTART_STALLED_S, PushRecovery
from firmware_io.client_types import Cancelled, DSATimeout, Frame
from firmware_io.layout import SensorLayout
from firmware_io.plausibility import FrameCheck
from firmware_io.transports.base import Transport, TransportError
from firmware_io.wire import requests as R
from firmware_io.wire.device_time import TimestampUnwrapper
from firmware_io.wire.errors import DeviceError, DSAError, DSAErrorCode, FrameDecodeError, ProtocolError
from firmware_io.wire.frames import decode_frame_payload
from firmware_io.wire.packets import BOOT_TERMINAL_QUERY, Packet, PacketId
from firmware_io.wire.parser import StreamParser
from firmware_io.wire.replies import ControllerInfo, MatrixInfoReply, SensitivityReply, SensorInfo, ThresholdReply

__all__ = ["Cancelled", "DSAClient", "DSATimeout", "Frame"]

READ_SIZE = 4096
CANCEL_POLL_S = 0.05
"""While a cancel predicate is set, no single read waits longer than this."""
MAX_QUEUED_REPLIES = 64
"""Non-frame packets kept for a command to look through; older ones are dropped (a streaming device
that keeps sending packets nobody asked for would otherwise fill the memory)."""
COUNTERS = ("frames", "frames_stale", "frames_ignored", "decode_errors", "frames_implausible", "unexpected_replies",
            "reconnects", "timeouts", "restarts")
"""What ``stats`` counts beside the parser's byte and packet counters."""


TransportSource = str | Transport | Callable[[], Transport]


class DSAClient(CommandExchange):
    """A DSACON32m reached through a URL (``tcp://..``, ``serial://..``, ``sim://``), a Transport,
    or a zero-argument callable returning a Transport (a URL or callable allows ``reconnect``)."""

    def __init__(
        self,
        source: TransportSource,
        *,
        rle: bool = True,
        gap_timeout: float = 1.0,
        reply_timeout: float = 2.0,
        open_timeout: float = 10.0,
        stop_timeout: float = 3.0,
        stop_tries: int = 3,
        flush_quiet: float = 0.1,
        flush_max: float = 1.0,
        max_skipped_frames: int = 4,
        max_queued_frames: int = 256,
        reconnect_tries: int = 5,
        backoff_initial: float = 0.1,
        backoff_max: float = 5.0,
        auto_reconnect: bool = True,
        restart_stalled_s: float | None = RESTART_STALLED_S,
        transport_opts: dict | None = None,
        on_wait: Callable[[str], None] | None = None,
    ) -> None:
        self._source = source
        self._transport: Transport | None = source if isinstance(source, Transport) else None
        self.rle = rle
        self.gap_timeout = gap_timeout
        self.reply_timeout = reply_timeout
        self.open_timeout = open_timeout
        self.stop_timeout = stop_timeout
        self.stop_tries = max(1, int(stop_tries))
        self.flush_quiet = flush_quiet
        self.flush_max = flush_max
        self.max_skipped_frames = max_skipped_frames
        self.reconnect_tries = max(1, int(reconnect_tries))
        self.backoff_initial = backoff_initial
        self.backoff_max = backoff_max
        self.auto_reconnect = auto_reconnect
        self._recovery = PushRecovery(restart_stalled_s)
        """When to send the push start again on an open link gone silent (``client_recovery``)."""
        self.transport_opts = dict(transport_opts or {})
        self.on_wait = on_wait
        """Told once per open, when the first stop goes unanswered, what the open now waits for and how long
        at most (``_waiting_line``): a booting controller keeps a console silent for 8 s, which looks hung."""

        self.parser = StreamParser()
        self.controller: ControllerInfo | None = None
        self.sensor: SensorInfo | None = None
        self.matrices: list[MatrixInfoReply] = []
        self.layout: SensorLayout | None = None
        self._plausible: FrameCheck | None = None
        self.streaming = False
        self._frames: deque[Frame] = deque()
        self._replies: deque[Packet] = deque(maxlen=MAX_QUEUED_REPLIES)
        self._last_rx = 0.0
        self._max_queued = max_queued_frames
        self._unwrap = TimestampUnwrapper()
        self._number = 0
        self._should_stop: Callable[[], bool] | None = None
        self._open_deadline: float | None = None
        self._open_bytes = self._open_boots = 0
        self._counts = dict.fromkeys(COUNTERS, 0)
        self._last_url = "the device"
        self.last_refusal: str | None = None
        """Why the newest frame that arrived whole but was refused (undecodable, implausible) was."""

    # -- lifecycle -------------------------------------------------------------------------------
    @property
    def url(self) -> str:
        if isinstance(self._source, str):
            return self._source
        if self._transport is not None:
            return getattr(self._transport, "url", "") or repr(self._transport)
        return self._last_url

    def open(self, should_stop: Callable[[], bool] | None = None) -> SensorLayout:
        """Stop any running acquisition, flush, query controller/sensor/matrix info -> the layout.

        Against a silent device this takes ``open_timeout``: it may be a controller still booting. Every query has a
        total deadline (``reply_timeout``) and the whole open one too (``open_timeout``): bytes
        that keep arriving without forming a reply (a wrong baud rate, another device on the line)
        do not extend them. ``should_stop`` is called at least every 50 ms meanwhile; once it
        returns True the transport is dropped and :class:`Cancelled` is raised.
        """
        with self._cancellable(should_stop):
            self._open_deadline = time.monotonic() + self.open_timeout
            self._open_bytes, self._open_boots = self.parser.stats.bytes_in, self.parser.stats.boot_queries
            try:
                return self._open()
            finally:
                self._open_deadline = None

    def _open(self) -> SensorLayout:
        self._ensure_transport()
        self.streaming = False
        acked = self._send_stop(1)
        if not acked:
            if self.on_wait is not None:
                self.on_wait(self._waiting_line())
            acked = self._send_stop(self.stop_tries - 1)
        while not acked and self._booting_maybe() and self._open_deadline - time.monotonic() > self.gap_timeout:
            acked = self._send_stop(1)
        self._flush(first_wait=self.flush_quiet if acked else self.flush_max)
        self._frames.clear()
        self.controller = ControllerInfo.decode(self._request(R.query_controller_info_request(), 0x01))
        self.sensor = SensorInfo.decode(self._request(R.query_sensor_info_request(), 0x02))
        if self.sensor.nb_matrices == 0:
            raise ProtocolError(f"{self.url}: controller reports no tactile matrices (is the sensor connected?)")
        self.matrices = [
            MatrixInfoReply.decode(self._request(R.query_matrix_info_request(m), 0x0B))
            for m in range(self.sensor.nb_matrices)
        ]
        return self._use_layout(SensorLayout.from_matrix_infos(r.to_matrix_info(i) for i, r in enumerate(self.matrices)))

    def _waiting_line(self) -> str:
        """What an open whose first stop went unanswered waits for, and the most it waits (its deadline)."""
        left = max(0.0, self._open_deadline - time.monotonic())
        why = " (one just powered on, or reset by its last host leaving, answers after about 8 s)"
        return (f"{self.url}: no answer yet; waiting up to {left:.0f} s for the controller to answer"
                f"{why if self._booting_maybe() else ''} ...")

    def _booting_maybe(self) -> bool:
        """Nothing but power-up queries came since the open began: a controller that was just powered
        on (or reset by a host leaving its Ethernet link) is deaf for about 8 s, so the open keeps asking
        within its deadline, as SDHLibrary's does; bytes of anything else go on to the queries' diagnosis."""
        p = self.parser.stats
        return p.bytes_in - self._open_bytes == len(BOOT_TERMINAL_QUERY) * (p.boot_queries - self._open_boots)

    def _use_layout(self, layout: SensorLayout) -> SensorLayout:
        self.layout = layout
        self._plausible = FrameCheck(layout)
        self.parser.set_cells(layout.n_taxels)
        return layout

    @classmethod
    def already_streaming(cls, transport: Transport, layout: SensorLayout, **opts: Any) -> DSAClient:
        """A client on a link that already streams frames of ``layout`` (a benchmark's or a test's
        feed of frame packets): no handshake, ``read_frame`` works at once, no reconnect."""
        client = cls(transport, auto_reconnect=False, **opts)
        client._use_layout(layout)
        client.streaming = True
        return client

    def start(self, should_stop: Callable[[], bool] | None = None) -> None:
        """Push mode: the controller sends frames as fast as it can (about 30 fps).
        ``should_stop``: as for :meth:`open`."""
        self._require_open()
        with self._cancellable(should_stop):
            self._ack(R.push_request(rle=self.rle, rate=1), frames_limit=None, timeout=self.stop_timeout)
        self.streaming = True
        self._recovery.started(time.monotonic(), self.parser.stats.boot_queries)

    def _restart_if_stalled(self) -> None:
        """Push mode that went silent with the link still open (the controller was power-cycled):
        send the push start again when ``PushRecovery`` says so."""
        now = time.monotonic()
        if not self.streaming or self._frames or not self._recovery.due(now, self.parser.stats.boot_queries):
            return
        try:
            self._ack(R.push_request(rle=self.rle, rate=1), frames_limit=None, timeout=self.gap_timeout)
        except DSAError:
            self._recovery.tried(now, ok=False)
            return  # still booting (or not a DSACON32m any more): tried again later
        self._counts["restarts"] += 1
        if self._recovery.tried(time.monotonic(), ok=True):
            self._unwrap.reset()  # its clock restarted at power-on

    @contextlib.contextmanager
    def _cancellable(self, should_stop: Callable[[], bool] | None):
        """Check ``should_stop`` between reads; on Cancelled drop the transport (no stop handshake
        with a device that may never answer) so that ``close()`` afterwards returns at once."""
        previous, self._should_stop = self._should_stop, should_stop
        try:
            yield
        except Cancelled:
            self._drop_transport()
            self.layout = None
            self.streaming = False
            raise
        finally:
            self._should_stop = previous

    def stop(self) -> None:
        """Stop acquisition. Frames already received stay queued for read_frame."""
        self.streaming = False
        if not self._send_stop(self.stop_tries):
            raise DSATimeout(f"{self.url}: controller did not acknowledge stop after {self.stop_tries} tries")

    def close(self, stop_timeout: float | None = None) -> None:
        """Stop (one bounded try) and release the transport. Never hangs, never raises.

        ``stop_timeout`` bounds the stop handshake (default: the gap timeout of a silent line,
        up to ``self.stop_timeout`` while the device keeps sending); a service shutting down passes
        a fraction of a second."""
        transport = self._transport
        if transport is None:
            return
        try:
            if not transport.closed:
                self._send_stop(1, timeout=stop_timeout)
        except (DSAError, OSError, Cancelled):
            pass
        finally:
            self._transport = None
            self.streaming = False
            self.layout = None  # open() again (lazily reopening a URL) before reading frames
            self.parser.reset()
            self._unwrap.reset()
            with contextlib.suppress(OSError):
                transport.close()

    def reconnect(self) -> SensorLayout:
        """Reopen after a transport failure with exponential backoff; resume push mode if it was on."""
        if isinstance(self._source, Transport):
            raise TransportError(f"{self.url}: cannot reconnect a client given an open transport; pass a URL")
        was_streaming = self.streaming
        delay = self.backoff_initial
        last: Exception | None = None
        for attempt in range(self.reconnect_tries):
            self._drop_transport()
            if attempt:
                time.sleep(delay)
                delay = min(delay * 2, self.backoff_max)
            try:
                layout = self.open()
                if self.layout is not None and layout.n_taxels != self.parser.n_cells:
                    self.parser.set_cells(layout.n_taxels)
                if was_streaming:
                    self.start()
                self._counts["reconnects"] += 1
                return layout
            except (TransportError, DSAError) as exc:
                last = exc
        self.streaming = False
        raise TransportError(f"{self.url}: reconnect failed after {self.reconnect_tries} tries: {last}")

    def __enter__(self) -> DSAClient:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- frames ----------------------------------------------------------------------------------
    def read_frame(self, timeout: float = 1.0, newest: bool = False) -> Frame | None:
        """The next frame, or None after ``timeout`` seconds. ``newest``: drop queued stale frames.

        After a transport failure it reconnects (if allowed) and keeps waiting until the deadline.
        ``timeout <= 0`` polls: takes in what has arrived without blocking, up to the first whole frame
        (``_pump_available``; a transport failure is raised, not reconnected), not counted as a timeout.
        """
        self._require_open()
        deadline = time.monotonic() + timeout
        if newest or (timeout <= 0 and not self._frames):
            self._pump_available(until_frame=not newest)
        if newest:
            self._keep_newest()
        if timeout <= 0:
            return self._frames.popleft() if self._frames else None
        while not self._frames:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                self._counts["timeouts"] += 1
                return None
            try:
                self._pump(min(remaining, self.gap_timeout))
                self._restart_if_stalled()
            except TransportError:
                if not self.auto_reconnect or isinstance(self._source, Transport):
                    raise
                self.reconnect()
            if newest:
                self._keep_newest()
        return self._frames.popleft()

    def poll_frame(self, timeout: float = 1.0) -> Frame:
        """One frame on request (acquisition stopped). Handles firmware <= R288 that pushes instead."""
        self._require_open()
        if self.streaming:
            frame = self.read_frame(timeout, newest=True)
            if frame is None:
                raise DSATimeout(f"{self.url}: no frame within {timeout:g} s")
            return frame
        self._discard_queued()
        self._ack(R.single_frame_request(rle=self.rle), frames_limit=None, timeout=timeout)
        frame = self.read_frame(timeout)
        if frame is None:
            raise DSATimeout(f"{self.url}: no frame within {timeout:g} s after a single-frame request")
        if self.controller is not None and self.controller.single_frame_broken:
            # Old firmware started pushing: stop it, drain what it sent, continue with this frame.
            self._send_stop(self.stop_tries)
            self._flush(first_wait=self.flush_quiet)
            self._discard_queued()
        return frame

    # -- other commands --------------------------------------------------------------------------
    def get_sensitivity(self, matrix: int) -> SensitivityReply:
        return SensitivityReply.decode(self._request(R.get_sensitivity_request(matrix), 0x12))

    def set_sensitivity(self, matrix: int, value: float, persistent: bool = False) -> None:
        """Persistent writes get no reply from the firmware (and wear its memory: ~100,000 writes)."""
        req = R.SetSensitivityRequest(matrix, value, persistent=persistent)
        self._command(req.to_packet(), expect_reply=not persistent)

    def get_threshold(self, matrix: int) -> int:
        return ThresholdReply.decode(self._request(R.get_threshold_request(matrix), 0x14)).threshold

    def set_threshold(self, matrix: int, threshold: int, persistent: bool = False) -> None:
        if self.controller is not None and self.controller.sw_version < 268:
            raise DeviceError(DSAErrorCode.FEATURE_NOT_SUPPORTED, 0x13)
        req = R.SetThresholdRequest(matrix, threshold, persistent=persistent)
        self._command(req.to_packet(), expect_reply=not persistent)

    @property
    def stats(self) -> dict[str, int]:
        p = self.parser.stats
        out = dict(self._counts)
        out.update(
            bytes_dropped=p.bytes_dropped,
            packets_dropped=p.packets_dropped + self._counts["decode_errors"],
            crc_errors=p.crc_errors,
            bad_headers=p.bad_headers,
            boot_queries=p.boot_queries,
            bytes_in=p.bytes_in,
        )
        return out

    # -- internals: transport --------------------------------------------------------------------
    def _ensure_transport(self) -> Transport:
        if self._transport is None:
            if isinstance(self._source, str):
                from firmware_io.transports import open_transport

                self._transport = open_transport(self._source, **self.transport_opts)
            elif callable(self._source):
                self._transport = self._source()
                self._last_url = self.url  # the factory's device, named in messages after it is dropped
            else:
                raise TransportError(f"{self.url}: the transport is closed")
        return self._transport

    def _drop_transport(self) -> None:
        transport, self._transport = self._transport, None
        if transport is not None and not isinstance(self._source, Transport):
            with contextlib.suppress(OSError):
                transport.close()
        self.parser.reset()
        self._unwrap.reset()

    def _require_open(self) -> None:
        if self.layout is None:
            raise DSAError("call open() first")
        if self._transport is None and isinstance(self._source, Transport):
            raise TransportError(f"{self.url}: the client is closed")

    def _write(self, data: bytes) -> None:
        self._ensure_transport().write(data)

    def _pump(self, timeout: float) -> int:
        """Read once (up to ``timeout``) and parse: frames go to the frame queue, other packets to
        ``self._replies``. Returns the number of bytes read (0 on a quiet line)."""
        should_stop = self._should_stop
        if should_stop is not None:
            if should_stop():
                raise Cancelled(f"{self.url}: cancelled")
            timeout = min(timeout, CANCEL_POLL_S)
        data = self._ensure_transport().read(READ_SIZE, timeout)
        now = time.monotonic()
        if not data:
            # Silent for a whole gap timeout with bytes pending: the packet being waited for
            # will not complete (a corrupt length); rescan what is behind it.
            if self.parser.pending and now - self._last_rx >= self.gap_timeout:
                self._dispatch(self.parser.flush_pending())
            return 0
        self._last_rx = now
        self._dispatch(self.parser.feed(data))
        return len(data)

    def _pump_available(self, limit: int = 64, until_frame: bool = False) -> None:
        """Take in whatever bytes are already waiting, without blocking (at most ``limit`` reads);
        ``until_frame``: stop once a frame is queued, so a poll returns it without first parsing
        the frames a burst holds behind it."""
        for _ in range(limit):
            if until_frame and self._frames:
                return
            data = self._ensure_transport().read(READ_SIZE, 0.0)
            if not data:
                return
            self._last_rx = time.monotonic()  # else a blocking read soon after takes the line for silent
            self._dispatch(self.parser.feed(data))

    def _dispatch(self, packets: list[Packet]) -> None:
        for packet in packets:
            if packet.packet_id == PacketId.FULL_FRAME:
                self._queue_frame(packet)
            else:
                self._replies.append(packet)

    def _queue_frame(self, packet: Packet) -> None:
        if self.layout is None:
            self._counts["frames_ignored"] += 1
            return
        try:
            raw_ts, values = decode_frame_payload(packet.payload, self.layout.n_taxels)
        except FrameDecodeError as exc:
            self._counts["decode_errors"] += 1
            self.last_refusal = str(exc)
            return
        problem = None if self._plausible is None else self._plausible.problem(values)
        if problem is not None:
            self._counts["frames_implausible"] += 1  # corrupt bits the CRC let through: never classified
            self.last_refusal = problem
            return
        frame = Frame(self._number, self._unwrap(raw_ts), packet.received, values)
        self._recovery.last_frame_at = time.monotonic()
        self._number += 1
        self._counts["frames"] += 1
        if len(self._frames) >= self._max_queued:
            self._frames.popleft()
            self._counts["frames_stale"] += 1
        self._frames.append(frame)

    def _keep_newest(self) -> None:
        while len(self._frames) > 1:
            self._frames.popleft()
            self._counts["frames_stale"] += 1

    def _discard_queued(self) -> None:
        self._counts["frames_stale"] += len(self._frames)
        self._frames.clear()

    def _flush(self, first_wait: float) -> None:
        """Read and parse until the line is quiet: ``first_wait`` for the first byte, then
        ``flush_quiet`` between chunks, never longer than ``max(first_wait, flush_max)``."""
        start = time.monotonic()
        end = start + max(first_wait, self.flush_max)
        last, quiet = start, first_wait
        while True:
            now = time.monotonic()
            if now >= end or now - last >= quiet:
                break
            if self._pump(min(quiet - (now - last), end - now)):
                last, quiet = time.monotonic(), self.flush_quiet
        self._replies.clear()
