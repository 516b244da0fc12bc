"""HID-to-UART bridges through hidapi: ``hid://VID:PID?serial=..&baud=115200`` (e.g. the CP2110).

Implements the Silicon Labs CP2110/CP2114 report format (AN434): data reports whose ID is the byte
count, and feature reports 0x50 (UART config), 0x41 (UART enable) and 0x43 (purge FIFOs) at open.
``device=`` supplies an object with ``hid.device``'s methods: the tests drive it against an emulated bridge.
"""

from __future__ import annotations

import contextlib
import struct
import time
from collections.abc import Callable

from firmware_io.transports.base import (
    DEFAULT_BAUD,
    DEFAULT_READ_SIZE,
    DeviceUnavailable,
    MissingDependency,
    ParsedURL,
    Transport,
    TransportError,
    parse_bridge,
)

__all__ = ["HidTransport", "data_reports", "uart_config_report"]

MAX_DATA_REPORT = 63
BAUD_RANGE = (300, 1_000_000)
"""What the CP2110/CP2114's UART runs at (data sheet): another baud= is the URL's error, found by the check
rather than as the bridge refusing its set-up report at every reconnect."""
REPORT_SIZE = 64
UART_ENABLE = 0x41
PURGE_FIFOS = 0x43
UART_CONFIG = 0x50
PARITY_NONE, FLOW_NONE, DATA_BITS_8, STOP_BITS_1 = 0, 0, 3, 0
EXTRA_HINT = "pip install 'tactile-handover[usb]'"


def uart_config_report(baud: int) -> bytes:
    """Feature report 0x50 for ``baud`` 8N1 without flow control."""
    return struct.pack(">BIBBBB", UART_CONFIG, baud, PARITY_NONE, FLOW_NONE, DATA_BITS_8, STOP_BITS_1)


def data_reports(data: bytes) -> list[bytes]:
    """Split bytes into CP2110 data reports ``[n, n bytes]``, n <= 63."""
    return [bytes([len(chunk)]) + chunk for chunk in (data[i : i + MAX_DATA_REPORT] for i in range(0, len(data), MAX_DATA_REPORT))]


class HidTransport(Transport):
    """A CP2110-style HID UART bridge."""

    def __init__(
        self,
        vid: int,
        pid: int,
        *,
        serial: str | None = None,
        baud: int = DEFAULT_BAUD,
        device: object | None = None,
        url: str = "",
    ) -> None:
        self.url = url or f"hid://{vid:04x}:{pid:04x}"
        self._closed = True
        self._buf = bytearray()
        if device is None:
            try:
                import hid
            except ImportError:
                raise MissingDependency(f"{self.url}: needs the Python package hidapi ({EXTRA_HINT})") from None
            if not hasattr(hid, "device"):
                raise MissingDependency(
                    f"{self.url}: the installed 'hid' module is not hidapi's (no hid.device); {EXTRA_HINT}"
                )
            device = hid.device()
        self._dev = device
        try:
            self._dev.open(vid, pid, serial) if serial else self._dev.open(vid, pid)
        except (OSError, ValueError) as exc:
            raise DeviceUnavailable(
                f"{self.url}: cannot open HID device {vid:04x}:{pid:04x} ({exc}); plugged in? permissions (udev rule)?"
            ) from None
        self._closed = False  # open: a failing set-up report is the device's line, not the closed one
        try:
            self._feature(uart_config_report(baud))
            self._feature(bytes([UART_ENABLE, 1]))
            self._feature(bytes([PURGE_FIFOS, 3]))
            self._dev.set_nonblocking(1)  # else hidapi's read with timeout 0 waits for the next report
        except BaseException:
            self.close()
            raise

    requires = ("hid", f"needs the Python package hidapi ({EXTRA_HINT})")

    @classmethod
    def url_settings(cls, parsed: ParsedURL, opts: dict) -> dict:
        parsed.check_options({"serial", "baud"})
        bridge = parse_bridge(parsed, opts)
        low, high = BAUD_RANGE
        if not low <= bridge["baud"] <= high:
            raise TransportError(f"{parsed.url}: baud={bridge['baud']} is outside what a CP2110 bridge can do "
                                 f"({low}..{high})")
        return {**bridge, "device": opts.get("device")}

    def _hid(self, failed: str, call: Callable, *args: object):
        """hidapi's ``call``; the OSError or ValueError it raises when the device goes away is one
        DeviceUnavailable line saying what ``failed``."""
        try:
            return call(*args)
        except (OSError, ValueError) as exc:
            self._check_open()
            raise DeviceUnavailable(f"{self.url}: {failed}: {exc}") from None

    def _feature(self, report: bytes) -> None:
        n = self._hid(f"feature report 0x{report[0]:02X} failed", self._dev.send_feature_report, list(report))
        if n is not None and n < 0:
            raise TransportError(f"{self.url}: the bridge refused feature report 0x{report[0]:02X}")

    def write(self, data: bytes) -> None:
        self._check_open()
        for report in data_reports(bytes(data)):
            n = self._hid("write failed (unplugged?)", self._dev.write, list(report))
            if n is not None and n < 0:
                raise DeviceUnavailable(f"{self.url}: write failed (unplugged?)")

    def read(self, max_bytes: int = DEFAULT_READ_SIZE, timeout: float = 0.1) -> bytes:
        self._check_open()
        deadline = time.monotonic() + max(timeout, 0.0)
        while len(self._buf) < max_bytes:
            wait_ms = 0 if self._buf else max(0, int((deadline - time.monotonic()) * 1000))
            report = self._hid("read failed (unplugged?)", self._dev.read, REPORT_SIZE, wait_ms)
            if not report:
                if self._buf or time.monotonic() >= deadline:
                    break
                continue
            n = report[0]
            if 1 <= n <= MAX_DATA_REPORT:
                self._buf += bytes(report[1 : 1 + n])
        out = bytes(self._buf[:max_bytes])
        del self._buf[:max_bytes]
        return out

    def _release(self) -> None:
        with contextlib.suppress(OSError, ValueError):
            self._dev.close()
