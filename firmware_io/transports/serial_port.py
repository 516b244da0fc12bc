"""RS232, USB-serial adapters and CDC-ACM devices through pyserial: 115200 8N1, no flow control.

The DSACON32m's serial settings are fixed (SDHLibrary hard-codes them). Reads wait with
``select`` on the port's file descriptor instead of changing pyserial's timeout per call,
which would reconfigure the port (a tcsetattr) on every read.
"""

from __future__ import annotations

import contextlib
import select
import time
from errno import EISDIR, ENOTTY

from firmware_io.transports.base import (
    DEFAULT_BAUD,
    DEFAULT_READ_SIZE,
    DeviceUnavailable,
    MissingDependency,
    ParsedURL,
    Transport,
    TransportError,
    parse_baud,
    parse_bool,
)

__all__ = ["SerialTransport"]


class SerialTransport(Transport):
    """``serial:///dev/ttyUSB0?baud=115200&exclusive=1`` or a plain ``/dev/ttyUSB0``."""

    def __init__(self, port: str, baud: int = DEFAULT_BAUD, exclusive: bool = True, url: str = "") -> None:
        self.url = url or f"serial://{port}"
        self.port = port
        try:
            import serial
        except ImportError:
            raise MissingDependency(f"{self.url}: needs pyserial (pip install pyserial)") from None
        self._serial_mod = serial
        try:
            self._ser = serial.Serial(
                port=port,
                baudrate=baud,
                bytesize=serial.EIGHTBITS,
                parity=serial.PARITY_NONE,
                stopbits=serial.STOPBITS_ONE,
                xonxoff=False,
                rtscts=False,
                dsrdtr=False,
                timeout=0,
                write_timeout=2.0,
                exclusive=exclusive or None,
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DeviceUnavailable(f"{self.url}: cannot open serial port: {_reason(exc, port)}") from None
        self.low_latency = _ask_low_latency(self._ser)
        try:
            self._fd: int | None = self._ser.fileno()
        except (AttributeError, serial.SerialException, OSError):
            self._fd = None
        self._closed = False

    requires = ("serial", "needs pyserial (pip install pyserial)")

    @classmethod
    def url_settings(cls, parsed: ParsedURL, opts: dict) -> dict:
        parsed.check_options({"baud", "exclusive"})
        if not parsed.location:
            raise TransportError(f"{parsed.url}: no port; use serial:///dev/ttyUSB0")
        return {"port": parsed.location,
                "baud": parse_baud(parsed, opts),
                "exclusive": parse_bool(parsed.url, "exclusive", parsed.option(opts, "exclusive", True))}

    def write(self, data: bytes) -> None:
        self._check_open()
        try:
            self._ser.write(data)
            self._ser.flush()
        except self._serial_mod.SerialTimeoutException:
            raise TransportError(f"{self.url}: write timed out (port blocked?)") from None
        except (self._serial_mod.SerialException, OSError) as exc:
            self._check_open()
            raise DeviceUnavailable(f"{self.url}: write failed: {exc}") from None

    def read(self, max_bytes: int = DEFAULT_READ_SIZE, timeout: float = 0.1) -> bytes:
        self._check_open()
        try:
            data = self._ser.read(max_bytes)
            if data or timeout <= 0:
                return data
            if self._fd is not None:
                ready, _, _ = select.select([self._fd], [], [], timeout)
                return self._ser.read(max_bytes) if ready else b""
            deadline = time.monotonic() + timeout
            while time.monotonic() < deadline:
                data = self._ser.read(max_bytes)
                if data:
                    return data
                time.sleep(0.002)
            return b""
        except (self._serial_mod.SerialException, OSError, ValueError) as exc:  # ValueError: select on fd -1
            self._check_open()
            raise DeviceUnavailable(f"{self.url}: read failed (unplugged?): {exc}") from None

    def _release(self) -> None:
        with contextlib.suppress(self._serial_mod.SerialException, OSError):
            self._ser.close()


def _ask_low_latency(ser) -> bool:
    """Ask the tty driver for low-latency mode (Linux ``ASYNC_LOW_LATENCY``), True if it took it.

    Why: a USB-serial adapter's driver may hold bytes that do not fill a packet; ftdi_sio keeps the
    chip's 16 ms latency timer unless the port is in low-latency mode (then 1 ms), so a frame's last
    bytes reached the daemon up to 16 ms late. Drivers and ports without it (a pty, a native UART,
    another OS) refuse, and nothing changes. Any failure counts as a refusal: pyserial raises ValueError
    or NotImplementedError, but its Linux code also looks up ``termios.TIOCGSERIAL`` (AttributeError where
    Python lacks it), and a nicety must not keep a working port from opening."""
    setter = getattr(ser, "set_low_latency_mode", None)
    if setter is None:
        return False
    try:
        setter(True)
    except Exception:  # any failure is a refusal (docstring)
        return False
    return True


def _context_errno(exc: Exception) -> int | None:
    """pyserial wraps the termios error of a port it cannot configure in a SerialException without errno."""
    inner = exc.__context__
    args = getattr(inner, "args", ())
    return args[0] if args and isinstance(args[0], int) else None


def _reason(exc: Exception, port: str) -> str:
    """pyserial's message, with what to check for the two common causes (no such device, no access)."""
    errno = getattr(exc, "errno", None) or _context_errno(exc)
    if errno in (ENOTTY, EISDIR):  # "Inappropriate ioctl for device": a file, /dev/null, a pipe: not a tty
        return (f"{port} is not a serial port; use the hand's serial device, "
                "e.g. /dev/ttyUSB0 or /dev/dsacon32m (`ls /dev/ttyUSB* /dev/ttyACM*`)")
    if errno == 2:
        return (f"{port} does not exist (hand's USB cable plugged in? `ls /dev/ttyUSB* /dev/ttyACM*`; "
                "the /dev/dsacon32m symlink needs the udev rules of deploy/INSTALL.md section 2)")
    if errno == 13:
        return f"no permission on {port} (the user needs group handover: udev rules, deploy/INSTALL.md section 2)"
    return str(exc)
