"""Host names of the UDP sinks, resolved in a background thread: never on the daemon's loop.

Why: ``getaddrinfo`` on a name whose DNS does not answer blocks for seconds and cannot be interrupted;
done where the sinks are built it held READY back and stalled SIGHUP past the watchdog. A name is
looked up again every ``RETRY_S`` while it fails; until then sends to it count as failed.
"""

from __future__ import annotations

import ipaddress
import logging
import socket
import threading
from collections.abc import Callable
from typing import Any

__all__ = ["ResolvedTarget", "log", "resolve_problem"]

log = logging.getLogger("handover.sinks")

RETRY_S = 30.0
"""How often a name that does not resolve is looked up again."""
CHECK_BOUND_S = 5.0
"""How long ``run --check`` waits for a name to resolve before it says it does not."""

Resolver = Callable[..., list]


def numeric_address(host: str, port: int) -> tuple[int, tuple] | None:
    """(family, address) of an address literal (127.0.0.1, ::1), without any lookup; None for a name."""
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        return None
    if ip.version == 4:
        return socket.AF_INET, (host, int(port))
    return socket.AF_INET6, (host, int(port), 0, 0)


def _lookup(host: str, port: int, resolve: Resolver) -> tuple[int, tuple]:
    info = resolve(host, port, type=socket.SOCK_DGRAM)[0]
    return info[0], info[4]


class ResolvedTarget:
    """``host:port`` whose ``address`` (family, sockaddr) is known at once for a literal, and later
    (or never) for a name; ``resolved`` is called once with it, from the lookup thread."""

    def __init__(self, host: str, port: int, resolved: Callable[[int, tuple], None],
                 resolve: Resolver | None = None, retry_s: float = RETRY_S) -> None:
        self.host, self.port = host, int(port)
        self.address: tuple[int, tuple] | None = numeric_address(host, port)
        self.error: str | None = None
        """Why the last lookup failed (None: resolved, or not tried yet)."""
        self._resolved = resolved
        self._resolve = resolve or socket.getaddrinfo
        self._retry_s = float(retry_s)
        self._stop = threading.Event()
        if self.address is not None:
            resolved(*self.address)
            return
        threading.Thread(target=self._run, name=f"resolve-{host}", daemon=True).start()

    def _run(self) -> None:
        logged = False
        while not self._stop.is_set():
            try:
                address = _lookup(self.host, self.port, self._resolve)
            except (OSError, UnicodeError, IndexError) as exc:
                self.error = str(exc) or type(exc).__name__
                if not logged:
                    logged = True
                    log.error("sink udp://%s:%d: the host name does not resolve (%s); events will go there once "
                              "it does (looked up again every %g s)", self.host, self.port, self.error, self._retry_s)
                self._stop.wait(self._retry_s)
                continue
            if self._stop.is_set():
                return
            self.address, self.error = address, None
            self._resolved(*address)
            if logged:
                log.warning("sink udp://%s:%d: the host name resolves now; events go there", self.host, self.port)
            return

    def close(self) -> None:
        """No more lookups (a lookup under way ends on its own and is dropped)."""
        self._stop.set()


def resolve_problem(host: str, port: int, bound_s: float = CHECK_BOUND_S, resolve: Resolver | None = None) -> str | None:
    """Why ``host`` does not resolve within ``bound_s`` (``run --check``), or None."""
    if numeric_address(host, port) is not None:
        return None
    box: list[Any] = []

    def run() -> None:
        try:
            box.append(_lookup(host, port, resolve or socket.getaddrinfo))
        except (OSError, UnicodeError, IndexError) as exc:
            box.append(exc)

    thread = threading.Thread(target=run, name=f"check-{host}", daemon=True)
    thread.start()
    thread.join(bound_s)
    if not box:
        return f"no answer from DNS within {bound_s:g} s"
    if isinstance(box[0], BaseException):
        return str(box[0]) or type(box[0]).__name__
    return None
