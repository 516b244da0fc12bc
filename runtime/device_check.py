"""``handover run --check --device``: open the configured device for a few seconds and say what came.

A config can be valid and the device still silent, on another port, at another baud rate or
serving another host; the check that does not open it says so, this one finds out. It reads
with the daemon's own client (no reconnect: one honest attempt) and reports frames, the rate
on the wall clock and on the device's clock, the pads and the controller; or one line saying
why it could not.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import dataclass

from firmware_io.wire.replies import serial_text
from runtime.health import one_line

__all__ = ["PROBE_CONNECT_S", "PROBE_S", "probe_device"]

PROBE_S = 3.0
"""How long the device is read: about 100 frames at 32 Hz, enough for a rate to mean something."""
PROBE_CONNECT_S = 10.0
"""The longest the check waits for a TCP connection (a URL's shorter connect_timeout is kept): the daemon may
wait an hour for a hand to power up, a check that says "for 3 s" must not (a silent host held it 2 minutes)."""


@dataclass
class DeviceProbe:
    """What a few seconds of reading the device gave."""

    url: str
    frames: int = 0
    seconds: float = 0.0
    device_rate_hz: float | None = None
    n_pads: int = 0
    n_taxels: int = 0
    firmware: str = ""
    sensor_serial: int | None = None
    errors: str = ""
    problem: str | None = None

    @property
    def rate_hz(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else 0.0

    def line(self) -> str:
        if self.problem:
            return f"device {self.url}: {self.problem}"
        clock = "" if self.device_rate_hz is None else f"; {self.device_rate_hz:.1f} Hz on the device's clock"
        serial = "" if self.sensor_serial is None else f", sensor serial {serial_text(self.sensor_serial)}"
        return (f"device {self.url}: {self.frames} frames in {self.seconds:.1f} s ({self.rate_hz:.1f} frames/s{clock}); "
                f"{self.n_pads} pads, {self.n_taxels} taxels, firmware {self.firmware}{serial}"
                + (f"; {self.errors}" if self.errors else ""))


def probe_device(url: str, seconds: float = PROBE_S, client_factory=None,
                 on_wait: Callable[[str], None] | None = None) -> DeviceProbe:
    """Open ``url``, stream for ``seconds``, close. Never raises: a failure is ``problem``. ``on_wait`` hears each
    wait as it starts, so the check never looks hung: the client's line when the open waits for a silent
    controller (``DSAClient.on_wait``: a boot takes 8 s), then the read of frames and its bound."""
    if client_factory is None:
        from firmware_io.client import DSAClient
        from firmware_io.transports import TransportError, validate_url

        asked = None
        with contextlib.suppress(TransportError):  # a URL that cannot open is said by the open below
            asked = validate_url(url).options.get("connect_timeout")
        bound = PROBE_CONNECT_S if asked is None else min(PROBE_CONNECT_S, float(asked))

        def client_factory(u: str):
            return DSAClient(u, auto_reconnect=False, transport_opts={"connect_timeout": bound}, on_wait=on_wait)

    probe = DeviceProbe(url)
    client = None
    try:
        client = client_factory(url)
        layout = client.open()
        probe.n_pads, probe.n_taxels = layout.n_matrices, layout.n_taxels
        if client.controller is not None:
            probe.firmware = client.controller.firmware
        if client.sensor is not None:
            probe.sensor_serial = int(client.sensor.serial_no)
        client.start()
        if on_wait is not None:
            on_wait(f"{url}: reading frames for up to {seconds:g} s ...")
        t0 = time.monotonic()
        end = t0 + seconds
        stamps: list[int] = []
        while (now := time.monotonic()) < end:
            frame = client.read_frame(timeout=min(0.5, end - now))
            if frame is not None:
                stamps.append(frame.timestamp_ms)
        probe.seconds = time.monotonic() - t0
        probe.frames = len(stamps)
        if len(stamps) >= 2 and stamps[-1] > stamps[0]:
            probe.device_rate_hz = (len(stamps) - 1) * 1000.0 / (stamps[-1] - stamps[0])
        stats = client.stats
        bad = {k: int(stats.get(k, 0)) for k in ("crc_errors", "decode_errors", "frames_implausible", "bytes_dropped")}
        probe.errors = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in bad.items() if v)
        if not stamps:
            probe.problem = (f"opened (firmware {probe.firmware}, {probe.n_taxels} taxels) but no frame came in "
                             f"{seconds:g} s after the push start")
    except Exception as exc:  # any failure to open or read is the answer, in one line
        probe.problem = f"cannot read it: {one_line(exc).removeprefix(f'{url}: ')}"
    finally:
        if client is not None:
            with contextlib.suppress(Exception):  # the probe's answer is already known; closing is best effort
                client.close(stop_timeout=0.5)
    return probe
