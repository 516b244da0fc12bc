"""A USB-serial bridge driven directly through pyusb: ``usb://VID:PID?serial=..&interface=..&chip=..&latency=..``.

For machines where the bridge has no kernel driver (or it must not be used): find the device, detach
a bound kernel driver, claim the bulk interface, set 115200 8N1 with the bridge's own requests
(``cdc``, ``ftdi``, ``cp210x`` or ``raw``; ``chip=auto`` picks by vendor id and interface class).
``backend=`` is passed to ``usb.core.find``: the tests drive this code against an emulated bridge.
"""

from __future__ import annotations

import contextlib
import errno
import struct
import time

from firmware_io.transports.base import (
    DEFAULT_BAUD,
    DEFAULT_READ_SIZE,
    DeviceUnavailable,
    MissingDependency,
    ParsedURL,
    Transport,
    TransportError,
    parse_bridge,
    parse_number,
)

__all__ = ["FTDI_LATENCY_MS", "UsbTransport", "ftdi_baud_divisor", "strip_ftdi_status"]

CHIPS = ("auto", "cdc", "ftdi", "cp210x", "raw")
VENDOR_CHIPS = {0x0403: "ftdi", 0x10C4: "cp210x"}
CDC_COMM_CLASS, CDC_DATA_CLASS = 0x02, 0x0A
FTDI_STATUS_BYTES = 2
FTDI_LATENCY_MS = 2
"""The FTDI latency timer the transport sets (``latency=`` in the URL, 1..255 ms; refused on a bridge the
URL names as another chip, ignored on one only found to be another at open): the chip holds a
packet that is not full until the timer runs out (16 ms after reset: half the sample period late).
But each timer period ends a transfer (with data or the two status bytes), and every transfer costs
the hot thread CPU, so a shorter timer costs more of a core: 2 ms keeps a frame's tail close for
little. CPU share per setting: results/design_figures.md."""
FTDI_FRACTION_CODES = (0, 3, 2, 4, 1, 5, 6, 7)  # eighths of the divisor -> the chip's encoding
_GONE_ERRNOS = {errno.ENODEV, errno.ENOENT, errno.ESHUTDOWN, errno.EPIPE, errno.EIO}
EXTRA_HINT = "pip install 'tactile-handover[usb]'"


def import_pyusb(url: str):
    """``usb.core`` and ``usb.util``, or a MissingDependency naming the extra."""
    try:
        import usb.core
        import usb.util
    except ImportError:
        raise MissingDependency(f"{url}: needs the Python package pyusb ({EXTRA_HINT})") from None
    return usb.core, usb.util


class UsbTransport(Transport):
    """Bulk endpoints of a USB-serial bridge."""

    def __init__(
        self,
        vid: int,
        pid: int,
        *,
        serial: str | None = None,
        interface: int | None = None,
        chip: str = "auto",
        baud: int = DEFAULT_BAUD,
        latency_ms: int = FTDI_LATENCY_MS,
        backend: object | None = None,
        url: str = "",
    ) -> None:
        self.url = url or f"usb://{vid:04x}:{pid:04x}"
        if chip not in CHIPS:
            raise TransportError(f"{self.url}: unknown chip {chip!r} (use {', '.join(CHIPS)})")
        core, util = import_pyusb(self.url)
        self._core, self._util = core, util
        self._closed = True
        self._detached: list[int] = []
        self._claimed: list[int] = []
        self._buf = bytearray()
        self._dev = self._find(vid, pid, serial, backend)
        try:
            self._setup(interface, chip, baud, latency_ms)
        except core.USBError as exc:
            self._release()
            raise self._usb_error("cannot set the device up", exc) from None
        except BaseException:
            self._release()
            raise
        self._closed = False

    requires = ("usb", f"needs the Python package pyusb ({EXTRA_HINT})")

    @classmethod
    def url_settings(cls, parsed: ParsedURL, opts: dict) -> dict:
        parsed.check_options({"serial", "interface", "chip", "baud", "latency"})
        url = parsed.url
        bridge = parse_bridge(parsed, opts)
        interface = parsed.option(opts, "interface")
        chip = str(parsed.option(opts, "chip", "auto")).lower()
        if chip not in CHIPS:
            raise TransportError(f"{url}: unknown chip {chip!r} (use {', '.join(CHIPS)})")
        known = VENDOR_CHIPS.get(bridge["vid"], "") if chip == "auto" else chip
        if parsed.option(opts, "latency") is not None and known not in ("", "ftdi"):
            raise TransportError(f"{url}: latency= sets an FTDI chip's latency timer and this is a {known} "
                                 "bridge, which has none: leave latency= out")
        if known == "ftdi":  # found by the URL check, not at every reconnect of a daemon that cannot use it
            try:
                ftdi_baud_divisor(bridge["baud"])
            except TransportError as exc:
                raise TransportError(f"{url}: {exc}") from None
        return {
            **bridge,
            "interface": None if interface in (None, "") else int(parse_number(url, "interface", interface, int, 0, 255)),
            "chip": chip,
            "latency_ms": int(parse_number(url, "latency", parsed.option(opts, "latency", FTDI_LATENCY_MS), int, 1,
                                           255)),
            "backend": opts.get("backend"),
        }

    # -- opening ------------------------------------------------------------------------------
    def _find(self, vid: int, pid: int, serial: str | None, backend: object | None):
        core, util = self._core, self._util

        def matches(dev) -> bool:
            if serial is None:
                return True
            try:
                return util.get_string(dev, dev.iSerialNumber) == serial
            except (core.USBError, ValueError, NotImplementedError):
                return False

        try:
            dev = core.find(idVendor=vid, idProduct=pid, backend=backend, custom_match=matches)
        except core.NoBackendError:
            raise MissingDependency(
                f"{self.url}: pyusb found no USB backend: install libusb-1.0 (Debian/Ubuntu: apt install libusb-1.0-0)"
            ) from None
        except core.USBError as exc:
            raise self._usb_error("cannot list USB devices", exc) from None
        if dev is None:
            which = f" with serial {serial!r}" if serial else ""
            raise DeviceUnavailable(f"{self.url}: no USB device {vid:04x}:{pid:04x}{which} (plugged in? lsusb)")
        return dev

    def _setup(self, interface: int | None, chip: str, baud: int, latency_ms: int) -> None:
        core, util, dev = self._core, self._util, self._dev
        try:
            cfg = dev.get_active_configuration()
        except core.USBError:
            cfg = None
        if cfg is None:
            dev.set_configuration()
            cfg = dev.get_active_configuration()
        intf = self._pick_interface(cfg, interface)
        number = intf.bInterfaceNumber
        self._claim(number)
        self._ep_in, self._ep_out = _bulk_pair(util, intf)
        self._packet = int(self._ep_in.wMaxPacketSize) or 64
        if chip == "auto":
            chip = VENDOR_CHIPS.get(int(dev.idVendor), "")
            if not chip:
                classes = {i.bInterfaceClass for i in cfg}
                chip = "cdc" if classes & {CDC_COMM_CLASS, CDC_DATA_CLASS} else "raw"
        self.chip = chip
        if chip == "cdc":
            comm = next((i.bInterfaceNumber for i in cfg if i.bInterfaceClass == CDC_COMM_CLASS), number)
            if comm != number:
                self._claim(comm)  # cdc_acm holds both interfaces; requests go to the communication one
            dev.ctrl_transfer(0x21, 0x20, 0, comm, struct.pack("<IBBB", baud, 0, 0, 8))  # SET_LINE_CODING 8N1
            dev.ctrl_transfer(0x21, 0x22, 0x0003, comm)  # SET_CONTROL_LINE_STATE: DTR | RTS
        elif chip == "ftdi":
            port = number + 1
            value, index = ftdi_baud_divisor(baud)
            dev.ctrl_transfer(0x40, 0x00, 0x0000, port)  # SIO_RESET
            dev.ctrl_transfer(0x40, 0x03, value, index | (port << 8 if number else 0))  # SIO_SET_BAUD_RATE
            dev.ctrl_transfer(0x40, 0x04, 0x0008, port)  # SIO_SET_DATA: 8 bits, no parity, 1 stop
            dev.ctrl_transfer(0x40, 0x02, 0x0000, port)  # SIO_SET_FLOW_CTRL: none
            dev.ctrl_transfer(0x40, 0x09, latency_ms, port)  # SIO_SET_LATENCY_TIMER
        elif chip == "cp210x":
            dev.ctrl_transfer(0x41, 0x00, 0x0001, number)  # IFC_ENABLE
            dev.ctrl_transfer(0x41, 0x1E, 0x0000, number, struct.pack("<I", baud))  # SET_BAUDRATE
            dev.ctrl_transfer(0x41, 0x03, 0x0800, number)  # SET_LINE_CTL: 8 data bits, no parity, 1 stop

    def _claim(self, number: int) -> None:
        """Detach a bound kernel driver (remembered, re-attached at close) and claim the interface."""
        core, dev = self._core, self._dev
        active = False
        with contextlib.suppress(NotImplementedError, core.USBError):
            active = bool(dev.is_kernel_driver_active(number))
        if active:
            dev.detach_kernel_driver(number)
            self._detached.append(number)
        self._util.claim_interface(dev, number)
        self._claimed.append(number)

    def _pick_interface(self, cfg, interface: int | None):
        util = self._util
        candidates = [i for i in cfg if i.bAlternateSetting == 0]
        if interface is not None:
            chosen = [i for i in candidates if i.bInterfaceNumber == interface]
            if not chosen:
                raise TransportError(f"{self.url}: the device has no interface {interface}")
            if _bulk_pair(util, chosen[0], required=False) is None:
                raise TransportError(f"{self.url}: interface {interface} has no bulk IN and OUT endpoints")
            return chosen[0]
        for intf in candidates:
            if _bulk_pair(util, intf, required=False) is not None:
                return intf
        raise TransportError(
            f"{self.url}: no interface with bulk IN and OUT endpoints; a HID bridge (e.g. CP2110) needs hid://"
        )

    # -- bytes --------------------------------------------------------------------------------
    def write(self, data: bytes) -> None:
        self._check_open()
        view = memoryview(bytes(data))
        while view:
            try:
                sent = self._ep_out.write(bytes(view), timeout=2000)
            except self._core.USBTimeoutError:
                raise TransportError(f"{self.url}: write timed out") from None
            except self._core.USBError as exc:
                self._check_open()
                raise self._usb_error("write failed", exc) from None
            view = view[sent:]

    def read(self, max_bytes: int = DEFAULT_READ_SIZE, timeout: float = 0.1) -> bytes:
        self._check_open()
        deadline = time.monotonic() + max(timeout, 0.0)
        while not self._buf:
            remaining = deadline - time.monotonic()
            # One packet a transfer: pyusb drops what a timed-out transfer had received, so a longer
            # transfer that times out between full packets of a frame loses them (a CRC error); a
            # one-packet transfer ends with the first packet, full or short. A 32 Hz frame is a few
            # packets, so the extra transfers cost little.
            try:
                chunk = bytes(self._ep_in.read(self._packet, timeout=max(1, int(remaining * 1000))))
            except self._core.USBTimeoutError:
                return b""
            except self._core.USBError as exc:
                if getattr(exc, "errno", None) == errno.ETIMEDOUT:
                    return b""
                self._check_open()
                raise self._usb_error("read failed", exc) from None
            if self.chip == "ftdi":
                chunk = strip_ftdi_status(chunk, self._packet)
            self._buf += chunk
            if not self._buf and time.monotonic() >= deadline:
                return b""
        out = bytes(self._buf[:max_bytes])
        del self._buf[:max_bytes]
        return out

    def _release(self) -> None:
        core, util, dev = self._core, self._util, getattr(self, "_dev", None)
        if dev is None:
            return
        for number in self._claimed:
            with contextlib.suppress(core.USBError, NotImplementedError):
                util.release_interface(dev, number)
        self._claimed = []
        for n in self._detached:
            with contextlib.suppress(core.USBError, NotImplementedError):
                dev.attach_kernel_driver(n)
        self._detached = []
        with contextlib.suppress(core.USBError, NotImplementedError):
            util.dispose_resources(dev)

    def _usb_error(self, what: str, exc: Exception) -> TransportError:
        code = getattr(exc, "errno", None)
        if code in _GONE_ERRNOS or "no such device" in str(exc).lower():
            return DeviceUnavailable(f"{self.url}: {what}: device gone ({exc})")
        if code in (errno.EACCES, errno.EPERM):
            return DeviceUnavailable(f"{self.url}: {what}: permission denied (install the udev rule in deploy/)")
        if code == errno.EBUSY:
            return DeviceUnavailable(f"{self.url}: {what}: interface busy (another program or a kernel driver)")
        return TransportError(f"{self.url}: {what}: {exc}")


def _bulk_pair(util, intf, required: bool = True):
    """(bulk IN, bulk OUT) endpoints of an interface, or None when ``required`` is False."""

    def bulk(direction):
        return util.find_descriptor(
            intf,
            custom_match=lambda e: util.endpoint_direction(e.bEndpointAddress) == direction
            and util.endpoint_type(e.bmAttributes) == util.ENDPOINT_TYPE_BULK,
        )

    ep_in, ep_out = bulk(util.ENDPOINT_IN), bulk(util.ENDPOINT_OUT)
    if ep_in is None or ep_out is None:
        if required:
            raise TransportError("interface has no bulk IN and OUT endpoints")
        return None
    return ep_in, ep_out


def ftdi_baud_divisor(baud: int) -> tuple[int, int]:
    """(wValue, wIndex) of SIO_SET_BAUD_RATE for FT232/FT2232 (3 MHz clock, 1/8 fractions)."""
    if not 183 <= baud <= 3_000_000:
        raise TransportError(f"baud rate {baud} outside what an FTDI bridge can do (183..3000000)")
    if baud >= 3_000_000:
        return 0, 0
    if baud >= 2_000_000:
        return 1, 0
    eighths = round(24_000_000 / baud)
    whole, frac = divmod(eighths, 8)
    code = FTDI_FRACTION_CODES[frac]
    return whole | ((code & 0x3) << 14), code >> 2


def strip_ftdi_status(data: bytes, packet_size: int) -> bytes:
    """Drop the two modem-status bytes at the start of every ``packet_size`` piece of an IN read."""
    if len(data) <= FTDI_STATUS_BYTES:
        return b""
    return b"".join(
        data[i + FTDI_STATUS_BYTES : i + packet_size] for i in range(0, len(data), packet_size)
    )
