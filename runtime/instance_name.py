"""Which daemon a line came from: the ``instance`` name in every event and model line, the health
file and /diagnostics.

Two hands (or a test rig beside the robot) may send to one UDP port; the name tells their lines
apart. Set ``instance`` in the config, or take the default: this host's name and the device's
(``robot-pc:ttyUSB0``, ``robot-pc:192.168.1.42:13000``, ``robot-pc:sim``), stable across restarts
and different for two devices on one host.
"""

from __future__ import annotations

import socket
from urllib.parse import urlsplit

__all__ = ["instance_problem"]

MAX_LENGTH = 64


def default_instance(url: str, hostname: str | None = None) -> str:
    """``<host>:<device>``: the device is the URL's path's last part (a serial port), else its
    host:port (TCP), else its scheme (sim, replay, usb with its VID:PID)."""
    host = (hostname or socket.gethostname() or "localhost").split(".")[0]
    text = url.strip()
    parts = urlsplit(text if "://" in text else f"serial://{text}")
    path = parts.path.rstrip("/")
    if parts.scheme in ("serial",) or (path and not parts.netloc):
        device = path.rsplit("/", 1)[-1] or parts.scheme
    elif parts.netloc:
        device = parts.netloc
    else:
        device = parts.scheme or "device"
    return f"{host}:{device}"[:MAX_LENGTH]


def instance_problem(name: object) -> str | None:
    """Why ``name`` cannot be an instance name, or None."""
    if not isinstance(name, str) or not name.strip():
        return f"must be a non-empty string, got {name!r}"
    if len(name) > MAX_LENGTH or not name.isprintable():
        shown = repr(name) if len(name) <= MAX_LENGTH else f"{name[:MAX_LENGTH]!r}... ({len(name)} characters)"
        return f"must be at most {MAX_LENGTH} printable characters, got {shown}"
    return None


def instance_of(cfg) -> str:
    """The config's ``instance``, else the default for its device."""
    return cfg.instance or default_instance(cfg.device.url)
