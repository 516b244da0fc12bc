"""SDH-2 Ethernet: the DSACON32m byte stream on TCP port 13000, unchanged from RS232.

TCP_NODELAY is set (the SDHLibrary comments it out on Linux, so small commands wait for
Nagle). A connection the device closes (recv returns nothing) is a DeviceUnavailable, never
an endless stream of empty reads.
"""

from __future__ import annotations

import contextlib
import ipaddress
import select
import socket

from firmware_io.transports.base import (
    DEFAULT_READ_SIZE,
    DeviceUnavailable,
    ParsedURL,
    Transport,
    TransportError,
    parse_number,
)

__all__ = ["DEFAULT_PORT", "URL_FORM", "TcpTransport"]

DEFAULT_PORT = 13000
"""The SDH-2's DSACON32m port, taken when a tcp:// URL names none."""
URL_FORM = f"tcp://HOST[:PORT] (default port {DEFAULT_PORT})"
"""A TCP device URL as a help text writes it: the default port is said where the URL is asked for."""
HELD_ELSEWHERE = "another client, e.g. the daemon, may hold the device: it serves one host at a time"
"""Why a device closes or resets a connection before sending a byte (a controller serving one host)."""


class TcpTransport(Transport):
    """``tcp://HOST[:PORT]?connect_timeout=3``."""

    def __init__(self, host: str, port: int = DEFAULT_PORT, connect_timeout: float = 3.0, url: str = "") -> None:
        self.url = url or f"tcp://{host}:{port}"
        self.host, self.port = host, port
        try:
            self._sock = socket.create_connection((host, port), timeout=connect_timeout)
        except socket.gaierror as exc:
            raise DeviceUnavailable(f"{self.url}: unknown host {host!r}: {exc.strerror}") from None
        except TimeoutError as exc:  # errno set: the kernel gave up first (its SYN retries, about 2 minutes)
            within = f"within {connect_timeout:g} s" if exc.errno is None else f"({exc.strerror or exc})"
            raise DeviceUnavailable(f"{self.url}: no answer {within} (hand powered? cable?)") from None
        except OSError as exc:
            raise DeviceUnavailable(f"{self.url}: cannot connect: {exc.strerror or exc} (hand powered, "
                                    f"host and port right? the SDH-2 listens on {DEFAULT_PORT})") from None
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock.settimeout(None)
        self._sock.setblocking(True)
        self._closed = False
        self._received = 0

    @classmethod
    def url_settings(cls, parsed: ParsedURL, opts: dict) -> dict:
        parsed.check_options({"connect_timeout"})
        if parsed.path not in ("", "/"):
            raise TransportError(f"{parsed.url}: a tcp URL has no path ({parsed.path!r}); use tcp://HOST:PORT")
        host, port = _split_host_port(parsed.url, parsed.netloc)
        timeout = parse_number(parsed.url, "connect_timeout", parsed.option(opts, "connect_timeout", 3.0), float,
                               0.001, 3600.0)
        return {"host": host, "port": port, "connect_timeout": timeout}

    def write(self, data: bytes) -> None:
        self._check_open()
        try:
            self._sock.sendall(data)
        except OSError as exc:
            self._check_open()
            raise DeviceUnavailable(self._lost(f"connection lost while sending: {exc.strerror or exc}")) from None

    def read(self, max_bytes: int = DEFAULT_READ_SIZE, timeout: float = 0.1) -> bytes:
        self._check_open()
        try:
            ready, _, _ = select.select([self._sock], [], [], max(timeout, 0.0))
            if not ready:
                return b""
            data = self._sock.recv(max_bytes)
        except (OSError, ValueError) as exc:  # ValueError: select on a socket closed meanwhile
            self._check_open()
            raise DeviceUnavailable(self._lost(f"connection lost: {getattr(exc, 'strerror', None) or exc}")) from None
        if not data:
            self._check_open()
            raise DeviceUnavailable(self._lost("the device closed the connection"))
        self._received += len(data)
        return data

    def _lost(self, what: str) -> str:
        """The line for a lost connection; closed before the first byte, it says who may hold the device."""
        return (f"{self.url}: {what} before any byte came ({HELD_ELSEWHERE})" if not self._received
                else f"{self.url}: {what}")

    def _release(self) -> None:
        with contextlib.suppress(OSError):
            self._sock.shutdown(socket.SHUT_RDWR)
        self._sock.close()


def _split_host_port(url: str, netloc: str) -> tuple[str, int]:
    """``host``, ``host:port`` or ``[v6]:port``, each part checked (a port of ASCII digits in 1..65535,
    a host name IDNA can encode or an IP address), or one TransportError saying what to write."""
    if netloc.startswith("["):
        host, _, rest = netloc[1:].partition("]")
        port_text = rest[1:] if rest.startswith(":") else (rest or None)
        _check_ip6(url, host)
    else:
        host, _, port_text = netloc.rpartition(":") if ":" in netloc else (netloc, "", None)
        _check_host_name(url, host)
    if port_text is None:
        return host, DEFAULT_PORT
    if not (port_text.isascii() and port_text.isdigit() and len(port_text) <= 5 and 0 < int(port_text) < 65536):
        got = f", got {port_text[:12]!r}" if port_text else ""
        raise TransportError(f"{url}: expected tcp://HOST:PORT with a port 1..65535{got}")
    return host, int(port_text)


def _check_host_name(url: str, host: str) -> None:
    if not host:
        raise TransportError(f"{url}: no host; use tcp://192.168.1.42:13000")
    if any(c.isspace() or c in "@[]%/\\:" for c in host):
        raise TransportError(f"{url}: {host[:40]!r} is not a host name; use tcp://HOST:PORT "
                             "(an IPv6 address in brackets: tcp://[::1]:13000)")
    try:
        host.encode("idna")
    except UnicodeError:
        raise TransportError(f"{url}: {host[:40]!r} is not a valid host name (empty or over-long label?)") from None


def _check_ip6(url: str, host: str) -> None:
    try:
        ipaddress.IPv6Address(host)
    except ValueError:
        raise TransportError(f"{url}: [{host[:40]}] is not an IPv6 address; use e.g. tcp://[::1]:13000") from None
