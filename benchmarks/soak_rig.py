"""The soak benchmark's rig: an emulated DSACON32m whose faults are switched on and off by a
schedule, a listener for sd_notify datagrams (watchdog pings), and an RSS sampler.

The emulator is the project's DeviceEmulator behind its TCP server; a subclass only records what
it sent (device stamp, time and sequence number of every frame) and adds the two faults a schedule
needs that a probability plan cannot give: bursts (every frame of the next N corrupted, truncated
or preceded by garbage) and a garbage stream (0xAA at about the serial line's byte rate, commands
ignored: a wrong baud rate or another device on the line).
"""

from __future__ import annotations

import contextlib
import itertools
import os
import socket
import time

from firmware_io.emulator.device import DeviceEmulator, FaultPlan
from firmware_io.emulator.server import TcpEmulatorServer
from trainer.bench.harness import DatagramListener
from trainer.bench.throughput import proc_mem_mb

GARBAGE_BYTES_PER_S = 11520  # 115200 baud, 8N1


class ScheduledEmulator(DeviceEmulator):
    """A DeviceEmulator with faults switched by the soak's schedule (thread-safe enough: the
    schedule sets plain attributes the server thread reads)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.sent: list[tuple[int, float, int]] = []
        """(device stamp ms as on the wire, monotonic time, sequence number) of every frame emitted."""
        self._burst_kind = ""
        self._burst_left = 0
        self.garbage_until = 0.0
        self._garbage_t = 0.0

    # -- schedule controls ------------------------------------------------------------------
    def burst(self, kind: str, frames: int) -> None:
        """The next ``frames`` frames each get fault ``kind`` (crc, garbage or drop)."""
        self._burst_kind, self._burst_left = kind, int(frames)

    def burst_active(self) -> bool:
        return self._burst_left > 0

    def unplug(self) -> None:
        self.disconnected = True
        self.stats.disconnects += 1

    def stall_for(self, seconds: float, now: float | None = None) -> None:
        now = time.monotonic() if now is None else now
        self._stall_until = now + seconds
        self._origin += seconds
        self.stats.stalls += 1

    def stream_garbage(self, seconds: float, now: float | None = None) -> None:
        """0xAA instead of the controller for ``seconds``; the link drops first (the host reconnects into it)."""
        now = time.monotonic() if now is None else now
        self.garbage_until = now + seconds
        self._garbage_t = now
        self._origin += seconds  # the recording resumes where it stopped
        self.unplug()

    # -- the emulator's view ------------------------------------------------------------------
    def feed(self, data: bytes, now: float | None = None) -> None:
        now = self.clock() if now is None else now
        if now < self.garbage_until:
            return  # another device: commands go nowhere
        super().feed(data, now)

    def read(self, max_bytes: int = 4096, now: float | None = None) -> bytes:
        now = self.clock() if now is None else now
        if now < self.garbage_until and not self.disconnected:
            n = min(max_bytes, int((now - self._garbage_t) * GARBAGE_BYTES_PER_S))
            if n <= 0:
                return b""
            self._garbage_t = now
            return b"\xaa" * n
        return super().read(max_bytes, now)

    def seconds_until_output(self, now: float | None = None) -> float | None:
        now = self.clock() if now is None else now
        if now < self.garbage_until and not self.disconnected:
            return 0.01
        return super().seconds_until_output(now)

    def _emit_frame(self, now: float) -> None:
        """Record the stamp the frame carries on the wire (``stamp_of``: the device clock restarts at
        every power cycle, which every TCP drop is) and give it the burst's damage, if one is on."""
        self.sent.append((self.stamp_of(self._next), now, self._next))
        if self._burst_left <= 0:
            super()._emit_frame(now)
            return
        self._burst_left -= 1
        saved = self.faults
        self.faults = FaultPlan(**{self._burst_kind: 1.0})
        try:
            super()._emit_frame(now)
        finally:
            self.faults = saved


def serve(emulator: ScheduledEmulator) -> TcpEmulatorServer:
    return TcpEmulatorServer(emulator, host="127.0.0.1", port=0).start()


class NotifyListener(DatagramListener):
    """An sd_notify socket: the times (CLOCK_MONOTONIC) of WATCHDOG=1 pings and how many
    READY/RELOADING/STOPPING came."""

    def __init__(self, path: str) -> None:
        self.path = path
        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        sock.bind(path)
        self.pings: list[float] = []
        self.counts = {"READY=1": 0, "RELOADING=1": 0, "STOPPING=1": 0}
        super().__init__(sock, "soak-notify")

    def on_datagram(self, data: bytes, t: float) -> None:
        now = time.monotonic()
        for line in data.decode(errors="replace").splitlines():
            if line == "WATCHDOG=1":
                self.pings.append(now)
            elif line in self.counts:
                self.counts[line] += 1

    def close(self) -> None:
        super().close()
        with contextlib.suppress(OSError):
            os.unlink(self.path)


def rss_mb(pid: int) -> float | None:
    """Resident memory of a process in MB (None once it is gone)."""
    try:
        return proc_mem_mb(pid).get("VmRSS")
    except OSError:
        return None


def watchdog_gaps(pings: list[float], start: float, end: float, limit_s: float) -> list[tuple[float, float]]:
    """Intervals longer than ``limit_s`` without a ping between ``start`` and ``end``: each one is
    a time systemd's watchdog (WatchdogSec = limit_s) would have fired."""
    return [(a, b) for a, b in ping_intervals(pings, start, end) if b - a > limit_s]


def ping_intervals(pings: list[float], start: float, end: float) -> list[tuple[float, float]]:
    """The silences between consecutive watchdog pings (and the run's start and end)."""
    return list(itertools.pairwise([start, *[p for p in pings if start <= p <= end], end]))
