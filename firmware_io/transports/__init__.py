"""Open a DSACON32m byte link by URL, like pyserial's ``serial_for_url`` or python-can's interfaces.

=====================================  =============================================================
``serial:///dev/ttyUSB0?baud=115200``  RS232 / USB-serial adapter / CDC-ACM (pyserial), 8N1, no flow
``/dev/ttyUSB0``, ``COM3``             same as ``serial://``
``tcp://192.168.1.42:13000``           SDH-2 Ethernet (port 13000 by default)
``usb://0403:6001?serial=..``          USB-serial bridge driven directly by pyusb (extra ``usb``)
``hid://10c4:ea80``                    HID-to-UART bridge such as the CP2110 (hidapi, extra ``usb``)
``sim://?seed=0&events=40``            the simulated hand behind an emulated controller, in process
``replay://PATH?speed=1.0|max``        a recording (.hrec, .dsa, .bag) behind an emulated controller
=====================================  =============================================================

Each scheme maps to ``"module:Class"``; the module is imported only when the scheme is used,
so pyusb and hidapi are needed only by those who use them. ``register_transport`` adds one.
"""

from __future__ import annotations

import importlib
import importlib.util
import re
from collections.abc import Callable

from firmware_io.transports.base import (
    MAX_BAUD,
    MAX_EVENTS,
    DeviceUnavailable,
    EndOfStream,
    MissingDependency,
    ParsedURL,
    Transport,
    TransportError,
    parse_bool,
    parse_number,
    parse_vid_pid,
)

__all__ = [
    "TRANSPORTS",
    "DeviceUnavailable",
    "EndOfStream",
    "MissingDependency",
    "Transport",
    "TransportError",
    "open_transport",
    "register_transport",
    "validate_url",
]

TRANSPORTS: dict[str, str | type] = {
    "serial": "firmware_io.transports.serial_port:SerialTransport",
    "tcp": "firmware_io.transports.tcp:TcpTransport",
    "usb": "firmware_io.transports.usb:UsbTransport",
    "hid": "firmware_io.transports.hid:HidTransport",
    "sim": "firmware_io.transports.emulated:SimTransport",
    "replay": "firmware_io.transports.emulated:ReplayTransport",
}

_WINDOWS_PORT = re.compile(r"^COM\d+$", re.IGNORECASE)


def register_transport(scheme: str, target: str | type) -> None:
    """Add or replace a scheme: ``target`` is a Transport class or ``"module:Class"``."""
    TRANSPORTS[scheme.lower()] = target


def _normalise(url: str) -> str:
    """A bare device path is a serial port, as in pyserial."""
    text = url.strip()
    if text.startswith("/") or _WINDOWS_PORT.match(text):
        return "serial://" + text
    return text


def _load(scheme: str, url: str) -> type:
    target = TRANSPORTS.get(scheme)
    if target is None:
        known = ", ".join(f"{s}://" for s in TRANSPORTS)
        where = f"unknown scheme {scheme + '://'!r}" if scheme else "no scheme"
        raise TransportError(f"{url}: {where}; use one of {known} or a /dev path")
    if not isinstance(target, str):
        return target
    module_name, _, class_name = target.partition(":")
    module = importlib.import_module(module_name)
    return getattr(module, class_name)


def open_transport(url: str, **opts: object) -> Transport:
    """Open the link a URL names. Keyword options override the URL's ``?key=value`` options.

    Raises TransportError for a bad URL, DeviceUnavailable when the device is absent or
    refuses, MissingDependency when an optional package is missing (the message names the extra).
    """
    if not isinstance(url, str) or not url.strip():
        raise TransportError("empty device URL; use e.g. serial:///dev/ttyUSB0 or tcp://192.168.1.42:13000")
    url = _normalise(url)
    parsed = ParsedURL(url)
    cls = _load(parsed.scheme, url)
    return cls.from_url(parsed, **opts)


def validate_url(url: str) -> ParsedURL:
    """Check a device URL without opening anything: scheme, location, options and their values,
    and the optional package the scheme needs.

    Raises the TransportError (MissingDependency for a missing package) that ``open_transport``
    would raise for the same mistake, so a bad URL is a config error, not an endless retry.
    A scheme added with ``register_transport`` is checked by its class's ``check_url(parsed)``
    classmethod when it has one (otherwise only the scheme is checked).
    """
    if not isinstance(url, str) or not url.strip():
        raise TransportError("empty device URL; use e.g. serial:///dev/ttyUSB0 or tcp://192.168.1.42:13000")
    url = _normalise(url)
    parsed = ParsedURL(url)
    target = TRANSPORTS.get(parsed.scheme)
    check = _CHECKS.get(parsed.scheme) if isinstance(target, str) and target == _BUILTIN.get(parsed.scheme) else None
    if check is not None:
        check(parsed)
        return parsed
    cls = _load(parsed.scheme, url)  # unknown scheme -> TransportError
    custom = getattr(cls, "check_url", None)
    if callable(custom):
        custom(parsed)
    return parsed


def _check_serial(p: ParsedURL) -> None:
    p.check_options({"baud", "exclusive"})
    if not p.location:
        raise TransportError(f"{p.url}: no port; use serial:///dev/ttyUSB0")
    parse_number(p.url, "baud", p.options.get("baud", 115200), int, 1, MAX_BAUD)
    parse_bool(p.url, "exclusive", p.options.get("exclusive", True))
    _need(p.url, "serial", "needs pyserial (pip install pyserial)")


def _check_tcp(p: ParsedURL) -> None:
    from firmware_io.transports.tcp import parse_tcp_url

    parse_tcp_url(p, p.options.get("connect_timeout", 3.0))


def _check_usb(p: ParsedURL) -> None:
    from firmware_io.transports.usb import CHIPS, EXTRA_HINT

    p.check_options({"serial", "interface", "chip", "baud"})
    parse_vid_pid(p.url, p.location)
    if p.options.get("interface", "") != "":
        parse_number(p.url, "interface", p.options["interface"], int, 0, 255)
    chip = p.options.get("chip", "auto").lower()
    if chip not in CHIPS:
        raise TransportError(f"{p.url}: unknown chip {chip!r} (use {', '.join(CHIPS)})")
    parse_number(p.url, "baud", p.options.get("baud", 115200), int, 1, MAX_BAUD)
    _need(p.url, "usb", f"needs the Python package pyusb ({EXTRA_HINT})")


def _check_hid(p: ParsedURL) -> None:
    from firmware_io.transports.hid import EXTRA_HINT

    p.check_options({"serial", "baud"})
    parse_vid_pid(p.url, p.location)
    parse_number(p.url, "baud", p.options.get("baud", 115200), int, 1, MAX_BAUD)
    _need(p.url, "hid", f"needs the Python package hidapi ({EXTRA_HINT})")


def _check_emulated(p: ParsedURL, allowed: set[str]) -> None:
    from firmware_io.transports.emulated import _COMMON, _emulator_options, _parse_speed

    p.check_options(_COMMON | allowed)
    _emulator_options(p, {})  # fault plan, old_firmware, start_ms, seed
    parse_bool(p.url, "loop", p.options.get("loop", False))
    _parse_speed(p.url, p.options.get("speed", 1.0))


def _check_sim(p: ParsedURL) -> None:
    _check_emulated(p, {"seed", "events", "realtime", "speed"})
    parse_number(p.url, "events", p.options.get("events", 40), int, 1, MAX_EVENTS)
    parse_bool(p.url, "realtime", p.options.get("realtime", True))


def _check_replay(p: ParsedURL) -> None:
    _check_emulated(p, {"speed", "seed"})
    if not p.location:
        raise TransportError(f"{p.url}: no file; use replay:///path/to/file.hrec")


def _need(url: str, module: str, hint: str) -> None:
    if importlib.util.find_spec(module) is None:
        raise MissingDependency(f"{url}: {hint}")


_BUILTIN = dict(TRANSPORTS)
_CHECKS: dict[str, Callable[[ParsedURL], None]] = {
    "serial": _check_serial,
    "tcp": _check_tcp,
    "usb": _check_usb,
    "hid": _check_hid,
    "sim": _check_sim,
    "replay": _check_replay,
}
