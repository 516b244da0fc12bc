"""Datagrams in tests: what a robot controller does to the control socket (one datagram, from a fresh
socket), and a listener in the abstract namespace where the daemon sends to an ``@name`` address."""

from __future__ import annotations

import contextlib
import itertools
import os
import socket
from collections.abc import Iterator

_names = itertools.count()


def send_datagram(path: str, data: bytes) -> None:
    """``data`` as one datagram to the Unix socket at ``path`` (as ``runtime.control`` expects it)."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as s:
        s.sendto(data, path)


@contextlib.contextmanager
def abstract_listener(prefix: str) -> Iterator[tuple[str, socket.socket]]:
    """A datagram socket bound to a fresh abstract name (reads wait 2 s at most) and the ``@name``
    address that reaches it; closed on the way out."""
    name = f"{prefix}-{os.getpid()}-{next(_names)}"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        sock.bind("\0" + name)
        sock.settimeout(2)
        yield "@" + name, sock
