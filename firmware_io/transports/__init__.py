"""Open a DSACON32m byte link by URL, like pyserial's ``serial_for_url`` or python-can's interfaces.

=====================================  =============================================================
``serial:///dev/ttyUSB0?baud=115200``  RS232 / USB-serial adapter / CDC-ACM (pyserial), 8N1, no flow
``/dev/ttyUSB0``, ``COM3``             same as ``serial://``
``tcp://192.168.1.42:13000``           SDH-2 Ethernet (port 13000 by default)
``usb://0403:6001?serial=..``          USB-serial bridge driven directly by pyusb (extra ``usb``)
``hid://10c4:ea80``                    HID-to-UART bridge such as the CP2110 (hidapi, extra ``usb``)
``sim://?seed=0&events=40&lab=A``      the simulated hand (of lab A or B) behind an emulated controller
``replay://PATH?speed=1.0|max``        a recording (.hrec, .dsa, .bag) behind an emulated controller
``subject://?seed=0&lab=B``            a scripted simulated subject (of lab A or B) behind an emulated controller
=====================================  =============================================================

Each scheme maps to ``"module:Class"``; the module is imported only when the scheme is used,
so pyusb and hidapi are needed only by those who use them.
Every scheme goes through this one table, and each transport class checks its own URL
(``Transport.url_settings``): opening and validating cannot disagree.
"""

from __future__ import annotations

import importlib
import ipaddress
import os
import re
import socket

from firmware_io.transports.base import (
    DeviceUnavailable,
    EndOfStream,
    MissingDependency,
    ParsedURL,
    Transport,
    TransportError,
)

__all__ = [
    "TRANSPORTS",
    "DeviceUnavailable",
    "EndOfStream",
    "MissingDependency",
    "Transport",
    "TransportError",
    "device_key",
    "open_transport",
    "validate_url",
]

TRANSPORTS: dict[str, str] = {
    "serial": "firmware_io.transports.serial_port:SerialTransport",
    "tcp": "firmware_io.transports.tcp:TcpTransport",
    "usb": "firmware_io.transports.usb:UsbTransport",
    "hid": "firmware_io.transports.hid:HidTransport",
    "sim": "firmware_io.transports.emulated:SimTransport",
    "replay": "firmware_io.transports.emulated:ReplayTransport",
    "subject": "firmware_io.transports.emulated:SubjectTransport",
}

_WINDOWS_PORT = re.compile(r"^COM\d+$", re.IGNORECASE)


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
    module_name, _, class_name = target.partition(":")
    module = importlib.import_module(module_name)
    return getattr(module, class_name)


def open_transport(url: str, **opts: object) -> Transport:
    """Open the link a URL names. Keyword options override the URL's ``?key=value`` options.

    Raises TransportError for a bad URL, DeviceUnavailable when the device is absent or
    refuses, MissingDependency when an optional package is missing (the message names the extra).
    """
    parsed = _parse(url)
    return _load(parsed.scheme, parsed.url).from_url(parsed, **opts)


def validate_url(url: str) -> ParsedURL:
    """Check a device URL without opening anything: scheme, location, options and their values,
    and the optional package the scheme needs.

    Raises the TransportError (MissingDependency for a missing package) that ``open_transport``
    would raise for the same mistake, so a bad URL is a config error, not an endless retry.
    Each transport class checks its own URL (``check_url``).
    """
    parsed = _parse(url)
    _load(parsed.scheme, parsed.url).check_url(parsed)
    return parsed


def device_key(url: str) -> str:
    """Which device a URL reaches, one spelling for every way of writing it (the daemon's instance lock):
    options ignored, the scheme's case too; a serial port by its real path (a udev symlink is the port
    it names); a tcp host by the address it resolves to, IPv4 first (``localhost``, ``127.1``, ``0.0.0.0``
    and ``127.0.0.1`` are one host), with the default port filled in. A URL that cannot be read is itself."""
    try:
        parsed = _parse(url.split("?", 1)[0])
        if parsed.scheme == "serial":
            return "serial://" + os.path.realpath(parsed.location)
        if parsed.scheme != "tcp":
            return f"{parsed.scheme}://{parsed.location.rstrip('/').lower()}"
        settings = _load("tcp", parsed.url).url_settings(parsed, {})
    except TransportError:
        return url.strip()
    host, port = settings["host"], settings["port"]
    try:
        found = [info[4][0] for info in socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)]
    except (OSError, UnicodeError):
        found = []
    address = min(found, key=lambda a: ":" in a, default=host.lower())
    try:
        ip = ipaddress.ip_address(address)
    except ValueError:  # a name that does not resolve (yet): by its name
        return f"tcp://{address}:{port}"
    ip = getattr(ip, "ipv4_mapped", None) or ip
    if ip.is_unspecified:  # connecting to 0.0.0.0 (or ::) reaches this host
        ip = ipaddress.ip_address("127.0.0.1" if ip.version == 4 else "::1")
    return f"tcp://[{ip}]:{port}" if ip.version == 6 else f"tcp://{ip}:{port}"


def _parse(url: str) -> ParsedURL:
    if not isinstance(url, str) or not url.strip():
        raise TransportError("empty device URL; use e.g. serial:///dev/ttyUSB0 or tcp://192.168.1.42:13000")
    return ParsedURL(_normalise(url))
