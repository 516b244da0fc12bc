"""Emulated USB bridges: the DeviceEmulator behind a pyusb backend or a hidapi-like device object.

They let the ``usb://`` and ``hid://`` transports run their real code without the hardware or libusb
(``backend=EmulatedUsbBackend(emulator)`` or ``device=EmulatedCp2110(emulator)`` to ``open_transport``),
and record the set-up requests so a test can check the UART was configured 115200 8N1.
"""

from __future__ import annotations

import struct
import threading
import time
from dataclasses import dataclass, field

from firmware_io.emulator.device import DeviceEmulator

__all__ = ["EmulatedCp2110", "EmulatedUsbBackend"]

FTDI_STATUS = b"\x01\x60"  # modem status, line status: what an idle FT232R reports
FTDI_DEFAULT_LATENCY_MS = 16
"""An FTDI chip's latency timer after reset: it sends a packet that is not full (or its two status
bytes alone) only when the timer runs out; SIO_SET_LATENCY_TIMER (request 0x09) sets 1..255 ms."""


@dataclass
class _Desc:
    """A descriptor: pyusb only reads attributes."""

    fields: dict = field(default_factory=dict)

    def __getattr__(self, name: str):
        try:
            return self.__dict__["fields"][name]
        except KeyError:
            raise AttributeError(name) from None


def _device_desc(vid: int, pid: int, n_configs: int = 1) -> _Desc:
    return _Desc(
        dict(
            bLength=18, bDescriptorType=1, bcdUSB=0x0200, bDeviceClass=0, bDeviceSubClass=0, bDeviceProtocol=0,
            bMaxPacketSize0=64, idVendor=vid, idProduct=pid, bcdDevice=0x0600, iManufacturer=1, iProduct=2,
            iSerialNumber=3, bNumConfigurations=n_configs, address=7, bus=1, port_number=1, port_numbers=(1,),
            speed=2,
        )
    )


def _interface_desc(number: int, cls: int, n_eps: int) -> _Desc:
    return _Desc(
        dict(
            bLength=9, bDescriptorType=4, bInterfaceNumber=number, bAlternateSetting=0, bNumEndpoints=n_eps,
            bInterfaceClass=cls, bInterfaceSubClass=0, bInterfaceProtocol=0, iInterface=0, extra_descriptors=[],
        )
    )


def _endpoint_desc(address: int, attributes: int, size: int) -> _Desc:
    return _Desc(
        dict(
            bLength=7, bDescriptorType=5, bEndpointAddress=address, bmAttributes=attributes, wMaxPacketSize=size,
            bInterval=0, bRefresh=0, bSynchAddress=0, extra_descriptors=[],
        )
    )


def _nap(deadline: float, wait: float | None) -> bool:
    """Sleep until the emulator's next output is due (``wait`` seconds, None: unknown), at most
    until ``deadline`` (time.monotonic); False once the deadline has passed (the read times out)."""
    remaining = deadline - time.monotonic()
    if remaining <= 0:
        return False
    time.sleep(remaining if wait is None else min(max(wait, 0.0005), remaining))
    return True


class EmulatedUsbBackend:
    """A pyusb backend (duck-typed ``usb.backend.IBackend``) with one USB-serial bridge on it.

    ``chip``: ``cdc`` (interface 0 communication class with an interrupt endpoint, interface 1
    data class with bulk 0x81 IN / 0x02 OUT), ``ftdi`` (one vendor interface, bulk 0x81 / 0x02,
    two status bytes in front of every 64-byte IN packet) or ``cp210x`` (like ftdi without
    status bytes). ``kernel_driver`` pretends a kernel driver is bound until it is detached.
    ``unplugged = True`` pulls the bridge out (the emulator's ``disconnect`` fault does too);
    ``replug()`` plugs it in again.
    """

    PACKET = 64

    def __init__(
        self,
        emulator: DeviceEmulator,
        *,
        vid: int = 0x0403,
        pid: int = 0x6001,
        chip: str = "ftdi",
        serial: str = "DSA00001",
        kernel_driver: bool = True,
    ) -> None:
        self.emulator = emulator
        self.chip = chip
        self.latency_ms = FTDI_DEFAULT_LATENCY_MS
        """The FTDI latency timer (ms); SIO_SET_LATENCY_TIMER changes it."""
        self._held = b""
        """Bytes the bridge took from the emulator and has not handed over yet."""
        self.serial = serial
        self.device = _device_desc(vid, pid)
        self.kernel_driver = kernel_driver
        self.detached: list[int] = []
        self.claimed: set[int] = set()
        self.control_requests: list[tuple[int, int, int, int, bytes]] = []
        self.configuration: int | None = None
        self.unplugged = False
        self.read_sizes: list[int] = []
        """Bytes each bulk IN transfer asked for (a transfer that times out loses what it had received)."""
        self._lock = threading.Lock()
        if chip == "cdc":
            self._interfaces = [
                (_interface_desc(0, 0x02, 1), [_endpoint_desc(0x83, 0x03, 16)]),
                (_interface_desc(1, 0x0A, 2), [_endpoint_desc(0x81, 0x02, self.PACKET), _endpoint_desc(0x02, 0x02, self.PACKET)]),
            ]
        else:
            self._interfaces = [
                (_interface_desc(0, 0xFF, 2), [_endpoint_desc(0x81, 0x02, self.PACKET), _endpoint_desc(0x02, 0x02, self.PACKET)])
            ]
        emulator.connect()

    # -- enumeration --------------------------------------------------------------------------
    def enumerate_devices(self):
        return [] if self.unplugged else ["bridge"]

    def get_parent(self, dev):
        return None

    def get_device_descriptor(self, dev):
        return self.device

    def get_configuration_descriptor(self, dev, config):
        return _Desc(
            dict(
                bLength=9, bDescriptorType=2, wTotalLength=32, bNumInterfaces=len(self._interfaces),
                bConfigurationValue=1, iConfiguration=0, bmAttributes=0x80, bMaxPower=50, extra_descriptors=[],
            )
        )

    def get_interface_descriptor(self, dev, intf, alt, config):
        if alt != 0:
            raise IndexError("no alternate setting")  # pyusb iterates alternates until IndexError
        return self._interfaces[intf][0]

    def get_endpoint_descriptor(self, dev, ep, intf, alt, config):
        return self._interfaces[intf][1][ep]

    # -- handles ------------------------------------------------------------------------------
    def open_device(self, dev):
        self._check_plugged()
        return "handle"

    def close_device(self, dev_handle):
        pass

    def set_configuration(self, dev_handle, config_value):
        self.configuration = config_value

    def get_configuration(self, dev_handle):
        if self.configuration is None:
            from usb.core import USBError

            raise USBError("Configuration not set", errno=None)
        return self.configuration

    def set_interface_altsetting(self, dev_handle, intf, altsetting):
        pass

    def is_kernel_driver_active(self, dev_handle, intf):
        return self.kernel_driver and intf not in self.detached

    def detach_kernel_driver(self, dev_handle, intf):
        self.detached.append(intf)

    def attach_kernel_driver(self, dev_handle, intf):
        if intf in self.detached:
            self.detached.remove(intf)

    def claim_interface(self, dev_handle, intf):
        if self.is_kernel_driver_active(dev_handle, intf):
            import errno

            from usb.core import USBError

            raise USBError("Resource busy", errno=errno.EBUSY)
        self.claimed.add(intf)

    def release_interface(self, dev_handle, intf):
        self.claimed.discard(intf)

    def clear_halt(self, dev_handle, ep):
        pass

    def reset_device(self, dev_handle):
        pass

    # -- transfers ----------------------------------------------------------------------------
    def ctrl_transfer(self, dev_handle, bmRequestType, bRequest, wValue, wIndex, data, timeout):
        self._check_plugged()
        if bmRequestType & 0x80:  # IN: only string descriptors are asked for
            if bRequest == 6 and wValue >> 8 == 3:
                index = wValue & 0xFF
                text = {1: "Emulated", 2: "DSACON32m bridge", 3: self.serial}.get(index, "")
                raw = b"\x04\x03\x09\x04" if index == 0 else bytes([2 + 2 * len(text), 3]) + text.encode("utf-16-le")
                n = min(len(data), len(raw))
                data[:n] = type(data)(data.typecode, raw[:n])
                return n
            return 0
        payload = bytes(data) if data is not None else b""
        self.control_requests.append((bmRequestType, bRequest, wValue, wIndex, payload))
        if self.chip == "ftdi" and bmRequestType == 0x40:
            if bRequest == 0x09 and wValue & 0xFF:
                self.latency_ms = wValue & 0xFF  # SIO_SET_LATENCY_TIMER
            elif bRequest == 0x00 and wValue in (0, 1):
                self._held = b""  # SIO_RESET: reset (0) or purge RX (1) empties the chip's buffer
        return len(payload)

    def bulk_write(self, dev_handle, ep, intf, data, timeout):
        self._check_plugged()
        with self._lock:
            self.emulator.feed(bytes(data))
        return len(data)

    def bulk_read(self, dev_handle, ep, intf, buff, timeout):
        """Bytes the emulator has sent, as the bridge hands them over. An FTDI chip holds bytes that do
        not fill a packet until its latency timer runs out (16 ms unless the host set it), and with
        nothing to send it answers its two status bytes alone at that moment; other bridges hand over
        what they have at once. Bytes a timed-out read did not take stay in the chip."""
        from usb.core import USBTimeoutError

        self._check_plugged()
        self.read_sizes.append(len(buff))
        status = FTDI_STATUS if self.chip == "ftdi" else b""
        room = len(buff) // self.PACKET * (self.PACKET - len(status)) or (len(buff) - len(status))
        start = time.monotonic()
        deadline = start + (timeout or 1000) / 1000.0
        flush_at = start + self.latency_ms / 1000.0 if status else start
        while True:
            with self._lock:
                if len(self._held) < room:
                    self._held += self.emulator.read(room - len(self._held))
                wait = self.emulator.seconds_until_output()
            now = time.monotonic()
            if now >= flush_at and (self._held or status):
                break  # what there is, or an FTDI chip's status bytes alone
            if len(self._held) >= self.PACKET - len(status):
                break  # a full packet goes at once
            if self.emulator.disconnected:
                self.unplugged = True
                self._check_plugged()
            if status:
                wait = flush_at - now if wait is None else min(wait, flush_at - now)
            if not _nap(deadline, wait):
                raise USBTimeoutError("Operation timed out", -7, 110)
        data, self._held = self._held[:room], self._held[room:]
        if status:
            step = self.PACKET - len(status)
            data = b"".join(status + data[i : i + step] for i in range(0, len(data), step)) or status
        buff[: len(data)] = type(buff)(buff.typecode, data)
        return len(data)

    def intr_write(self, dev_handle, ep, intf, data, timeout):
        raise NotImplementedError("the emulated bridge has no interrupt OUT endpoint")

    def intr_read(self, dev_handle, ep, intf, buff, timeout):
        raise NotImplementedError("the emulated bridge's interrupt endpoint carries no data")

    def iso_write(self, dev_handle, ep, intf, data, timeout):
        raise NotImplementedError

    def iso_read(self, dev_handle, ep, intf, buff, timeout):
        raise NotImplementedError

    def replug(self) -> None:
        """The bridge plugged in again after ``unplugged``: the chip lost its buffer and settings with
        its power (latency timer back to 16 ms), and the controller behind it was power-cycled too."""
        with self._lock:
            self._held = b""
            self.latency_ms = FTDI_DEFAULT_LATENCY_MS
            self.emulator.power_cycle()
        self.detached.clear()
        self.claimed.clear()
        self.configuration = None
        self.unplugged = False

    def _check_plugged(self) -> None:
        if self.unplugged:
            import errno

            from usb.core import USBError

            raise USBError("No such device (it may have been disconnected)", errno=errno.ENODEV)


BLOCKING_READ_S = 5.0
"""How long the CP2110 stand-in's blocking ``read`` waits on a silent line (hidapi: for ever)."""


class EmulatedCp2110:
    """A stand-in for ``hid.device()`` speaking the CP2110's report format to a DeviceEmulator."""

    def __init__(self, emulator: DeviceEmulator, vid: int = 0x10C4, pid: int = 0xEA80) -> None:
        self.emulator = emulator
        self.vid, self.pid = vid, pid
        self.feature_reports: list[bytes] = []
        self.uart_enabled = False
        self.uart_config: tuple[int, int, int, int, int] | None = None
        self.is_open = False
        self.unplugged = False
        self.blocking = True
        """hidapi's mode: ``read`` without a timeout (0) waits for a report unless set_nonblocking(1)."""
        self._pending = bytearray()

    def open(self, vendor_id: int = 0, product_id: int = 0, serial_number: str | None = None) -> None:
        if self.unplugged or (vendor_id, product_id) != (self.vid, self.pid):
            raise OSError("open failed")
        self.is_open = True
        self.emulator.connect()

    def close(self) -> None:
        self.is_open = False

    def set_nonblocking(self, v: int) -> int:
        self.blocking = not v
        return 0

    def send_feature_report(self, data) -> int:
        self._check()
        report = bytes(data)
        self.feature_reports.append(report)
        if report[0] == 0x41:
            self.uart_enabled = bool(report[1])
        elif report[0] == 0x50:
            self.uart_config = struct.unpack(">IBBBB", report[1:9])
        elif report[0] == 0x43:
            self._pending.clear()
        return len(report)

    def write(self, data) -> int:
        self._check()
        report = bytes(data)
        n = report[0]
        if not 1 <= n <= 63 or len(report) < 1 + n:
            return -1
        if self.uart_enabled:
            self.emulator.feed(report[1 : 1 + n])
        return len(report)

    def read(self, max_length: int, timeout_ms: int = 0) -> list[int]:
        """As cython-hidapi: ``timeout_ms > 0`` waits that long; 0 calls hid_read, which in blocking
        mode waits for the next report however long that takes (here: up to BLOCKING_READ_S)."""
        self._check()
        wait_s = timeout_ms / 1000.0 if timeout_ms > 0 else BLOCKING_READ_S if self.blocking else 0.0
        deadline = time.monotonic() + wait_s
        while not self._pending:
            if self.uart_enabled:
                self._pending += self.emulator.read(4096)
            if self._pending:
                break
            if self.emulator.disconnected:
                self.unplugged = True
                self._check()
            if not _nap(deadline, self.emulator.seconds_until_output()):
                return []
        n = min(63, max_length - 1, len(self._pending))
        chunk = bytes(self._pending[:n])
        del self._pending[:n]
        return [n, *chunk]

    def _check(self) -> None:
        if self.unplugged:
            raise OSError("read error (device disconnected)")
        if not self.is_open:
            raise ValueError("not open")
