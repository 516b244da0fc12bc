"""The one interface every byte transport implements, and its errors.

A transport moves raw bytes between the host and a DSACON32m; it knows nothing of packets.
``read`` waits at most ``timeout`` seconds and returns ``b""`` when nothing came, so a caller
can keep its own deadlines (the protocol uses a gap timeout, not a whole-packet timeout).
"""

from __future__ import annotations

import importlib.util
import math
import string
from abc import ABC, abstractmethod
from types import TracebackType
from typing import ClassVar
from urllib.parse import parse_qs, urlsplit

from firmware_io.errors import DEVICE_ERROR, HandoverError

__all__ = [
    "DEFAULT_BAUD", "DEFAULT_READ_SIZE", "MAX_EVENTS", "DeviceUnavailable", "EndOfStream", "MissingDependency",
    "ParsedURL", "Transport", "TransportError", "parse_baud", "parse_bool", "parse_bridge", "parse_number",
    "parse_speed"
]

DEFAULT_READ_SIZE = 4096


class TransportError(HandoverError, OSError):
    """A transport that cannot be opened or used; the message names the URL and the cause."""


class DeviceUnavailable(TransportError):
    """The device is not there: unplugged, refused, closed the connection, or never existed."""

    exit_code = DEVICE_ERROR


class EndOfStream(DeviceUnavailable):
    """A finite source (a replayed recording) has sent everything; reconnecting starts it again."""


class MissingDependency(TransportError):
    """An optional package or system library a transport needs is not installed."""


class Transport(ABC):
    """Bytes in, bytes out. Subclasses set ``url`` and implement the three methods.

    A transport opened by URL owns its URL: ``url_settings`` reads and checks every part of it
    (one place per transport), ``check_url`` runs those checks without opening anything (a
    config check), and ``from_url`` opens with the settings they found.
    """

    url: str = ""
    requires: ClassVar[tuple[str, str] | None] = None
    """``(import name, what to install)`` of an optional package the transport needs, or None."""

    @classmethod
    def url_settings(cls, parsed: ParsedURL, opts: dict) -> dict:
        """The constructor's keyword arguments from the URL and keyword options (which win), every value
        checked; raises one TransportError naming the URL and what to write instead."""
        return {}

    @classmethod
    def check_url(cls, parsed: ParsedURL) -> None:
        """What opening would refuse about the URL, without opening: its settings and the package it needs."""
        cls.url_settings(parsed, {})
        if cls.requires is not None and importlib.util.find_spec(cls.requires[0]) is None:
            raise MissingDependency(f"{parsed.url}: {cls.requires[1]}")

    @classmethod
    def from_url(cls, parsed: ParsedURL, **opts: object) -> Transport:
        return cls(**cls.url_settings(parsed, opts), url=parsed.url)

    @abstractmethod
    def write(self, data: bytes) -> None:
        """Send all of ``data`` or raise TransportError."""

    @abstractmethod
    def read(self, max_bytes: int = DEFAULT_READ_SIZE, timeout: float = 0.1) -> bytes:
        """Up to ``max_bytes`` bytes; ``b""`` if none arrived within ``timeout`` seconds."""

    def close(self) -> None:
        """Release the device; closing twice is harmless (``_release`` runs once)."""
        if self.closed:
            return
        self._closed = True
        self._release()

    def _release(self) -> None:  # noqa: B027 - a hook: an emulated device holds nothing to free
        """Free what the open transport holds (socket, port, handle); ``close`` calls it once."""

    @property
    def closed(self) -> bool:
        return getattr(self, "_closed", False)

    def _check_open(self) -> None:
        """Every transport refuses reads and writes after ``close`` with the same line; a transport calls it
        again when a read or write fails, since ``close`` from another thread meanwhile fails it too (a
        closed socket's select raised ValueError, a shut one read as the device hanging up)."""
        if self.closed:
            raise TransportError(f"{self.url}: transport is closed")

    def __enter__(self) -> Transport:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.url}>"


MAX_URL_CHARS = 4096
"""The longest device URL read: a path can be at most 4096 bytes (Linux PATH_MAX), and every error line
repeats the URL (a megabyte one made a megabyte log line)."""


def _unprintable(text: str) -> int | None:
    """Where ``text``'s first control or other unprintable character is, None when it has none."""
    return next((i for i, c in enumerate(text) if not c.isprintable()), None)


class ParsedURL:
    """A device URL split into scheme, location (host:port, VID:PID or path) and options.

    The one place URLs are split: whatever ``urlsplit`` or the query parser refuses (an unclosed
    ``[``, an invalid IPv6 literal, a control character, an option given twice) is a TransportError
    naming the URL, never a ValueError."""

    def __init__(self, url: str) -> None:
        if len(url) > MAX_URL_CHARS:
            raise TransportError(f"{url[:40]!r}...: a device URL of {len(url)} characters; write one of at most "
                                 f"{MAX_URL_CHARS} (the scheme, the device and its options)")
        self.url = url
        bad = _unprintable(url)
        if bad is not None:
            raise TransportError(f"{url!r}: unprintable character {url[bad]!r} at position {bad}; "
                                 "write the device URL on one line without control characters")
        try:
            parts = urlsplit(url)
        except ValueError as exc:
            raise TransportError(f"{url}: cannot read the location ({exc}); write an IPv6 host as "
                                 "tcp://[::1]:13000, and no other '[' or ']'") from None
        self.scheme = parts.scheme.lower()
        self.netloc = parts.netloc
        self.path = parts.path
        self.options: dict[str, str] = {}
        try:
            query = parse_qs(parts.query, keep_blank_values=True, strict_parsing=bool(parts.query))
        except ValueError:
            raise TransportError(f"{url}: cannot read the options after '?' (use key=value&key=value)") from None
        for key, values in query.items():
            if len(values) > 1:
                raise TransportError(f"{url}: option {key!r} given {len(values)} times; give it once")
            bad = _unprintable(values[0])
            if bad is not None:
                raise TransportError(f"{url}: option {key!r} decodes to the unprintable character {values[0][bad]!r}; "
                                     "give its value as printable text (no %00..%1F or %7F)")
            self.options[key] = values[0]

    @property
    def location(self) -> str:
        """``netloc + path``: a path given as ``scheme://relative/file`` keeps its first part."""
        return self.netloc + self.path

    def option(self, opts: dict, name: str, default: object = None) -> object:
        """Keyword options win over the URL's query string."""
        if name in opts and opts[name] is not None:
            return opts[name]
        return self.options.get(name, default)

    def check_options(self, allowed: set[str]) -> None:
        unknown = sorted(set(self.options) - allowed)
        if unknown:
            hint = ", ".join(sorted(allowed)) or "none"
            raise TransportError(f"{self.url}: unknown option {unknown[0]!r} (this transport takes: {hint})")


def parse_number(url: str, name: str, text: object, kind: type = float, minimum: float | None = None,
                 maximum: float | None = None) -> float:
    """One option value as a finite number in [minimum, maximum], or a TransportError naming the option
    (NaN and infinity would silently turn a timeout or a rate off)."""
    try:
        value = kind(text)
    except (TypeError, ValueError, OverflowError):
        raise TransportError(f"{url}: option {name}={text!r} is not a{'n integer' if kind is int else ' number'}") from None
    if isinstance(value, float) and not math.isfinite(value):
        raise TransportError(f"{url}: option {name}={text!r} must be a finite number")
    if minimum is not None and value < minimum:
        raise TransportError(f"{url}: option {name}={value} must be at least {minimum}")
    if maximum is not None and value > maximum:
        raise TransportError(f"{url}: option {name}={str(value)[:24]} must be at most {maximum}")
    return value


DEFAULT_BAUD = 115200
"""The DSACON32m's fixed serial speed (SDHLibrary hard-codes it): serial, usb and hid bridges start there."""
MAX_BAUD = 12_000_000
"""The fastest USB-serial bridges (FTDI high-speed); the DSACON32m itself runs at 115200."""


def parse_baud(parsed: ParsedURL, opts: dict) -> int:
    """The ``baud=`` option of a bridge's URL (a keyword option wins), 1..MAX_BAUD, DEFAULT_BAUD when left out."""
    return int(parse_number(parsed.url, "baud", parsed.option(opts, "baud", DEFAULT_BAUD), int, 1, MAX_BAUD))
MAX_EVENTS = 100_000
"""Scripted events of a simulated session (``sim://?events=``): about 28 hours at 1 s each."""


MAX_SPEED = 1e6
"""Playback faster than this is written ``max`` (as fast as the frames are read)."""
AS_FAST_AS_READ = ("max", "inf", "0")


def parse_speed(url: str, text: object, name: str = "speed") -> float | None:
    """A playback speed (the factor on recorded timing, 1.0 = real time) or None for ``max`` (also ``inf``
    or ``0``): the one reading of every speed option, in URLs and on command lines."""
    if text is None or str(text).strip().lower() in AS_FAST_AS_READ:
        return None
    return parse_number(url, name, text, float, 1 / MAX_SPEED, MAX_SPEED)


def parse_bool(url: str, name: str, text: object) -> bool:
    if isinstance(text, bool):
        return text
    t = str(text).strip().lower()
    if t in ("1", "true", "yes", "on"):
        return True
    if t in ("0", "false", "no", "off", ""):
        return False
    raise TransportError(f"{url}: option {name}={text!r} must be 0 or 1")


def parse_bridge(parsed: ParsedURL, opts: dict) -> dict:
    """What every USB bridge's URL says (``usb://`` and ``hid://``): ``vid`` and ``pid`` from ``VID:PID``,
    ``serial=`` (None when left out or empty) and ``baud=``."""
    vid, pid = parse_vid_pid(parsed.url, parsed.location)
    return {"vid": vid, "pid": pid, "serial": parsed.option(opts, "serial") or None, "baud": parse_baud(parsed, opts)}


def parse_vid_pid(url: str, location: str) -> tuple[int, int]:
    """``"0403:6001"`` (hex, as lsusb prints it) -> (0x0403, 0x6001)."""
    text = location.strip("/")
    parts = text.split(":")
    if len(parts) != 2 or not all(parts):
        raise TransportError(f"{url}: expected VID:PID in hex such as 0403:6001, got {text!r}")
    if not all(p.isascii() and all(c in string.hexdigits for c in p) for p in parts):  # int() also took -0, +4, 4_3
        raise TransportError(f"{url}: VID:PID must be hexadecimal such as 0403:6001, got {text!r}")
    vid, pid = (int(p, 16) for p in parts)
    if not (0 <= vid <= 0xFFFF and 0 <= pid <= 0xFFFF):
        raise TransportError(f"{url}: VID and PID are 16-bit hex numbers, got {text!r}")
    return vid, pid
