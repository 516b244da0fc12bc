"""One daemon per device and per health file: advisory locks the kernel releases when the holder dies.

Two daemons on one device fight over it, and two on one health file make the health flap. So the
daemon takes an exclusive ``flock`` on one lock file per device (named by ``device_key``, in
``$RUNTIME_DIRECTORY``, else ``$XDG_RUNTIME_DIR/handover``, else a per-user temp folder it owns) and one
beside the health file; a second daemon exits with one line naming the holder's pid.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import os
import stat
import tempfile
from dataclasses import dataclass
from pathlib import Path

from firmware_io.errors import HandoverError
from runtime.health import write_problem

__all__ = ["InstanceLockError", "device_lock_path", "held_by_other", "release", "take", "targets",
           "untrusted"]


class InstanceLockError(HandoverError, RuntimeError):
    """A lock is held by another daemon, or cannot be taken (one line saying which and what to do)."""


def lock_folder(environ: dict | None = None) -> Path:
    """Where device locks live (see the module docstring)."""
    env = os.environ if environ is None else environ
    if env.get("RUNTIME_DIRECTORY"):
        return Path(env["RUNTIME_DIRECTORY"].split(":")[0])
    if env.get("XDG_RUNTIME_DIR"):
        return Path(env["XDG_RUNTIME_DIR"]) / "handover"
    return Path(tempfile.gettempdir()) / f"handover-{os.getuid()}"


def device_lock_path(url: str, environ: dict | None = None) -> Path:
    """The lock file of a device URL: one file for every spelling of one device (transports.device_key)."""
    from firmware_io.transports import device_key

    digest = hashlib.sha256(device_key(url).encode()).hexdigest()[:16]
    return lock_folder(environ) / f"{DEVICE_PREFIX}{digest}.lock"


DEVICE_PREFIX = "device-"
"""A device lock's name begins so: its folder (``lock_folder``) must be this user's alone."""


def health_lock_path(health_file: str | os.PathLike) -> Path:
    p = Path(health_file)
    return p.with_name(f".{p.name}.lock")


@dataclass
class Held:
    """A lock this process holds (the open file keeps it)."""

    path: Path
    fd: int


def _holder(fd: int) -> str:
    """The pid an open lock file names, believed only from a file of this user (another's says anything)."""
    info = os.fstat(fd)
    if info.st_uid != os.geteuid():
        return f"a lock file of uid {info.st_uid}"
    text = os.pread(fd, 32, 0).decode(errors="replace").strip()
    return f"pid {text}" if text.isdigit() else "unknown pid"


def _open_folder(folder: Path) -> int:
    """A device lock's folder, opened without following a symbolic link and refused unless this user owns
    it and no one else may write there: another user who made ``$TMPDIR/handover-<uid>`` first would hold
    our locks or have us write into a folder of theirs. OSError with the line to print otherwise."""
    try:
        fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError as exc:
        if exc.errno in (errno.ELOOP, errno.ENOTDIR):
            raise OSError(f"lock folder {folder} is a symbolic link or not a folder: remove it (locks are never "
                          "written elsewhere)") from None
        raise
    if whose := untrusted(os.fstat(fd)):
        os.close(fd)
        raise OSError(f"lock folder {folder} is {whose}, not this user's (uid {os.geteuid()}) alone: remove it, or set "
                      "XDG_RUNTIME_DIR to a folder of this user's")
    return fd


def untrusted(info: os.stat_result, shared: bool = False) -> str | None:
    """Why a folder (its ``stat``) is not safe for our files, or None: a user who owns it or may write
    there can remove what we put there and put theirs in its place. ``shared`` also trusts root's
    folders, and others' writing in a sticky one (like /tmp: only a file's owner may remove it)."""
    if info.st_uid != os.geteuid() and not (shared and info.st_uid == 0):
        return f"owned by uid {info.st_uid}"
    if info.st_mode & 0o022 and not (shared and info.st_mode & stat.S_ISVTX):
        return "writable by others"
    return None


def _open(path: Path, flags: int) -> int:
    """Open a lock file that is a plain file of its own: never through a symbolic link (another user
    may plant one in a shared temp folder), nor a second hard link (the pid written into it would
    overwrite whatever file the name leads to), nor a FIFO (it would block the opener); a device
    lock only inside a folder of this user's alone (``_open_folder``, the name opened in it).
    OSError with the line to print otherwise."""
    folder = _open_folder(path.parent) if path.name.startswith(DEVICE_PREFIX) else None
    try:
        fd = os.open(path.name if folder is not None else path, flags | os.O_CLOEXEC | os.O_NOFOLLOW | os.O_NONBLOCK,
                     0o644, dir_fd=folder)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise OSError(f"{path} is a symbolic link: remove it (a lock is never followed elsewhere)") from None
        if exc.errno == errno.EISDIR:
            raise OSError(f"{path} is a folder: remove it (the lock is a file there)") from None
        raise
    finally:
        if folder is not None:
            os.close(folder)
    info = os.fstat(fd)
    if not stat.S_ISREG(info.st_mode) or info.st_nlink != 1:
        os.close(fd)
        kind = "a second name of another file" if stat.S_ISREG(info.st_mode) else "a special file"
        raise OSError(f"{path} is {kind}, not a lock file of its own: remove it")
    return fd


def take(what: str, path: Path) -> Held:
    """Lock ``path`` for this process and write its pid there; InstanceLockError when another holds it."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        fd = _open(path, os.O_RDWR | os.O_CREAT)
    except OSError as exc:
        hint = ("; make its folder writable for the daemon's user or choose another path"
                if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS) else "")
        raise InstanceLockError(f"cannot take the lock of {what} at {path}: {exc.strerror or exc}{hint}") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        holder = _holder(fd)
        os.close(fd)
        if exc.errno in (errno.EWOULDBLOCK, errno.EACCES):
            raise InstanceLockError(f"{what} is in use by another handover daemon ({holder}, lock {path}); "
                                    "stop that one first, or give this one another device and health_file") from None
        raise InstanceLockError(f"cannot take the lock of {what} at {path}: {exc.strerror or exc}") from None
    os.ftruncate(fd, 0)
    os.write(fd, f"{os.getpid()}\n".encode())
    return Held(path, fd)


def held_by_other(what: str, path: Path) -> str | None:
    """The line saying ``path`` is locked by another process, or None (the lock is not kept)."""
    if not os.path.lexists(path):
        return None
    try:
        fd = _open(path, os.O_RDONLY)
    except OSError:  # not a lock anyone holds (problem() says why the daemon would refuse it)
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except OSError:
        return f"{what} is in use by a running handover daemon ({_holder(fd)}, lock {path})"
    finally:
        os.close(fd)
    return None


def problem(what: str, path: Path) -> str | None:
    """Why ``run`` could not take the lock at ``path`` (a symbolic link, a FIFO, a read-only folder, a
    device lock folder not this user's alone), found by taking it as ``run`` does and letting go; None
    also when another daemon holds it (``held_by_other`` says so). ``run --check`` exits 2 on it, so
    systemd's ExecStartPre stops a service that would exit 2 at every restart."""
    try:
        release([take(what, path)])
    except InstanceLockError as exc:
        return None if held_by_other(what, path) else str(exc)
    return None


IN_PROCESS = ("sim:", "replay:", "subject:")
"""Devices each daemon emulates inside itself: nothing to share, nothing to lock."""


def targets(cfg) -> list[tuple[str, Path]]:
    """What one daemon of ``cfg`` must have to itself: its device (unless emulated in process), and
    its health file if it writes one."""
    out = []
    if not cfg.device.url.strip().lower().startswith(IN_PROCESS):
        out.append((f"device {cfg.device.url}", device_lock_path(cfg.device.url)))
    if cfg.health_file:
        out.append((f"health_file {cfg.health_file}", health_lock_path(cfg.health_file)))
    return out


def release(held: list[Held]) -> None:
    for h in held:
        with contextlib.suppress(OSError):
            os.close(h.fd)
    held.clear()


class Locks:
    """The locks one daemon holds, kept in step with its config: a reload that names another device or
    health file takes the new locks first (refused, the running config kept, when another daemon holds
    one) and lets go of those it no longer needs, so a second daemon is refused exactly while this one
    uses the resource."""

    def __init__(self, held: list[Held]) -> None:
        self.held = held

    @classmethod
    def take(cls, cfg) -> Locks:
        """Every lock of ``cfg``, or none (InstanceLockError for the first one held elsewhere)."""
        locks = cls([])
        if line := locks.retarget(cfg):
            raise InstanceLockError(line)
        return locks

    def retarget(self, cfg) -> str | None:
        """Hold ``cfg``'s locks instead of the current ones; the line saying why not (nothing changed), or None."""
        have = {h.path: h for h in self.held}
        new: list[Held] = []
        try:
            for what, path in targets(cfg):
                if path not in have:
                    new.append(take(what, path))
        except InstanceLockError as exc:
            release(new)
            return str(exc)
        if cfg.health_file and (line := write_problem(cfg.health_file)):  # its folder exists now (take made it)
            release(new)
            return line
        wanted = {path for _, path in targets(cfg)}
        release([h for h in self.held if h.path not in wanted])
        self.held = [h for h in self.held if h.path in wanted] + new
        return None

    def release(self) -> None:
        release(self.held)
