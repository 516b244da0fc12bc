"""What a robot controller does to the control socket in tests: one datagram, from a fresh socket."""

from __future__ import annotations

import socket


def send_datagram(path: str, data: bytes) -> None:
    """``data`` as one datagram to the Unix socket at ``path`` (as ``runtime.control`` expects it)."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as s:
        s.sendto(data, path)
