"""Who may talk to the control socket, and where it can live.

Why: ``grasp open`` silences the trigger, so only the daemon's user (or root) may send: a filesystem
socket is mode 600, and every datagram's sender credentials (SCM_CREDENTIALS) are checked, abstract
sockets included. ``socket_path_problem`` says before binding why a ``control.socket`` can never work
or could be taken over (a folder another user may swap it in);
``held``/``in_use_line``: a name another process holds stops the daemon and fails ``run --check``.
"""

from __future__ import annotations

import errno
import os
import socket
import stat
import struct
from pathlib import Path

from runtime.instance_lock import untrusted

__all__ = ["ANCILLARY_BYTES", "allow_credentials", "held", "in_use_line", "may_steer", "restrict", "sender_uid",
           "socket_path_problem", "untrusted_folder"]

MAX_ADDRESS_BYTES = 107
"""sun_path holds 108 bytes with the closing NUL (Linux)."""
SOCKET_MODE = 0o600
_UCRED = struct.Struct("3i")  # pid, uid, gid
ANCILLARY_BYTES = socket.CMSG_SPACE(_UCRED.size)


def socket_path_problem(address: str) -> str | None:
    """Why ``control.socket`` = ``address`` cannot be bound, or None (a stale socket file is fine:
    it is replaced; one another process is reading is found at bind time)."""
    name = address[1:] if address.startswith("@") else address
    if address.startswith("@") and not name.strip():
        return (f"control.socket {address!r}: an abstract socket needs a name after the @ (e.g. @handover-control); "
                "or use a path, e.g. /run/handover/control.sock")
    if len(name.encode()) > MAX_ADDRESS_BYTES:
        return (f"control.socket {address}: {len(name.encode())} bytes, longer than a Unix socket address "
                f"({MAX_ADDRESS_BYTES}); choose a shorter path, e.g. /run/handover/control.sock")
    if address.startswith("@"):
        return None
    path = Path(address)
    try:
        mode = path.lstat().st_mode
    except FileNotFoundError:
        mode = None
    except OSError as exc:
        return f"control.socket {address}: cannot look at it ({exc.strerror or exc})"
    if mode is not None and not stat.S_ISSOCK(mode):
        what = "a symlink" if stat.S_ISLNK(mode) else "a folder" if stat.S_ISDIR(mode) else "a file"
        return f"control.socket {address}: exists and is not a socket ({what}); remove it or choose another path"
    if not path.parent.is_dir():
        return (f"control.socket {address}: cannot bind: folder {path.parent} does not exist; create it (RuntimeDirectory= "
                "in the unit file) or choose another path")
    if why := untrusted_folder(path.parent):
        return (f"control.socket {address}: {why}: another user could replace the socket and get the robot's messages; "
                "choose a folder of this user's or root's, e.g. /run/handover (RuntimeDirectory= in the unit file)")
    return None


def untrusted_folder(folder: Path) -> str | None:
    """A folder on the way to a file of ours (the socket, the capture folder's), as named or as resolved, that another user owns or may write
    to (``instance_lock.untrusted``, shared: root's and sticky ones are fine), or a symbolic link of
    another user's (re-pointed, it leads elsewhere)."""
    named, real = Path(os.path.abspath(folder)), Path(os.path.realpath(folder))
    for each in dict.fromkeys([named, *named.parents, real, *real.parents]):
        try:
            info = each.lstat()
        except OSError as exc:
            return f"cannot look at folder {each} ({exc.strerror or exc})"
        if stat.S_ISLNK(info.st_mode):
            why = None if info.st_uid in (os.geteuid(), 0) else f"a symbolic link of uid {info.st_uid}"
        else:
            why = untrusted(info, shared=True)
        if why:
            return f"folder {each} is {why}"
    return None


def in_use_line(address: str) -> str:
    """What to say about a control socket another process holds."""
    if address.startswith("@"):
        return (f"control.socket {address}: in use by another process (another daemon? any local user may take an "
                "abstract name); stop it, or choose another name or a path such as /run/handover/control.sock")
    return f"control.socket {address}: in use by another process (another daemon?); stop it or choose another path"


def held(address: str) -> bool:
    """Whether another process holds ``address`` now: a socket file it reads (a stale one refuses a
    connect), or an abstract name (tried by binding it and letting go at once)."""
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    try:
        if address.startswith("@"):
            probe.bind(b"\0" + address[1:].encode())
            return False
        probe.connect(address)
    except OSError as exc:
        return address.startswith("@") and exc.errno == errno.EADDRINUSE
    finally:
        probe.close()
    return True


def allow_credentials(sock: socket.socket) -> None:
    """Ask the kernel for each datagram's sender credentials (pid, uid, gid)."""
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_PASSCRED, 1)


def restrict(address: str) -> None:
    """A freshly bound filesystem socket: only its owner may send (abstract names have no mode)."""
    if not address.startswith("@"):
        os.chmod(address, SOCKET_MODE)


def sender_uid(ancillary: list[tuple[int, int, bytes]]) -> int | None:
    """The sender's uid from ``recvmsg``'s ancillary data, or None when the kernel gave none."""
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == socket.SCM_CREDENTIALS and len(data) >= _UCRED.size:
            return _UCRED.unpack(data[:_UCRED.size])[1]
    return None


def may_steer(uid: int | None, own_uid: int | None = None) -> bool:
    """Only the daemon's own user and root may send robot messages (no credentials: refused)."""
    own = os.geteuid() if own_uid is None else own_uid
    return uid is not None and uid in (own, 0)
