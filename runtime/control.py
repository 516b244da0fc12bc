"""The daemon's control socket: short text datagrams from the robot, e.g. ``grasp closed``.

A Unix datagram socket (``[control] socket``, a path or ``@abstract`` name) read by its own thread, so
the hot path never blocks on it; messages are only queued for the next frame. Anything unknown is
counted and logged once. A stale socket file is replaced, a live one (another daemon) is not. Only
the daemon's own user and root may send (runtime.control_access).

Messages (ASCII, case and surrounding white space ignored): ``grasp closed`` (arm the onset trigger
now), ``grasp open`` (no event until the hand is empty or closed again), ``arm moving`` and
``arm still`` (runtime.arm_motion), ``outcome WORD`` (what happened after the last event: taken, kept,
dropped or a class name; runtime.capture).
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import socket
import stat
import threading
import time
from collections.abc import Callable
from pathlib import Path

from runtime import control_access as access

__all__ = ["MAX_DATAGRAM", "POLL_S", "ControlSocket", "MessageLog", "log", "parse_message"]

log = logging.getLogger("handover.control")
daemon_log = logging.getLogger("handover.daemon")

MAX_DATAGRAM = 512
POLL_S = 0.2
"""Longest the reader blocks: bounds how long ``stop`` takes."""
MESSAGES: dict[str, tuple[str, bool]] = {
    "grasp closed": ("grasp", True), "grasp open": ("grasp", False),
    "arm moving": ("arm", True), "arm still": ("arm", False),
}
"""Every control datagram the daemon knows: text -> (topic, value); and ``outcome WORD`` (``OUTCOME``)."""
OUTCOME = "outcome"
MAX_WORD = 64
"""The longest outcome word (a class name is at most that long: firmware_io.recordings.recording)."""
GRASP_LOG_INTERVAL_S = 1.0
"""At most one log line per this many seconds for each kind of robot message (the rest are counted in the next)."""


def parse_message(data: bytes) -> tuple[str, bool | str] | None:
    """``("grasp", closed)`` or ``("arm", moving)`` for a known message (``MESSAGES``), ``("outcome", word)``
    for ``outcome WORD`` (the word is checked by field capture), None for anything else (also for a datagram
    over ``MAX_DATAGRAM`` bytes, whose start may look like a message)."""
    if len(data) > MAX_DATAGRAM:
        return None
    try:
        text = data.decode("ascii").strip().lower()
    except UnicodeDecodeError:
        return None
    words = text.split()
    if len(words) == 2 and words[0] == OUTCOME and len(words[1]) <= MAX_WORD and words[1].isprintable():
        return OUTCOME, words[1]
    return MESSAGES.get(" ".join(words))


class ControlSocket:
    """Reads control datagrams on ``address``; calls ``on_grasp(closed, "control")``, ``on_arm(moving, "control")``
    or ``on_outcome(word, "control")``."""

    def __init__(self, address: str, on_grasp: Callable[[bool, str], None],
                 on_arm: Callable[[bool, str], None] | None = None,
                 on_outcome: Callable[[str, str], None] | None = None) -> None:
        self.address = address
        self.on_grasp = on_grasp
        self.on_arm = on_arm
        self.on_outcome = on_outcome
        self.received = 0
        self.garbage = 0
        """Datagrams that were not a known message (the first is logged, all are counted)."""
        self.refused = 0
        """Datagrams from another user than the daemon's (or root): dropped (the first is logged)."""
        self._sock: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._rebind_failed = False
        self._bound: tuple[int, int] | None = None
        """(device, inode) of the socket file this daemon bound: a file put in its place is not ours."""
        self._replaced_said = False

    def start(self) -> ControlSocket:
        """Bind and start reading; OSError (one line naming the socket) when it cannot bind."""
        try:
            self._sock = self._bound_socket(self._bind_address())
        except OSError as exc:
            if exc.errno is None:  # already our one line (control_access)
                raise
            if exc.errno == errno.EADDRINUSE and self.address.startswith("@"):
                raise OSError(access.in_use_line(self.address)) from None
            raise OSError(f"control.socket {self.address}: cannot bind ({exc.strerror or exc})") from None
        self._bound = self._file_id()
        self._thread = threading.Thread(target=self._loop, name="handover-control", daemon=True)
        self._thread.start()
        log.info("control socket %s: listening (%s)", self.address, " / ".join((*MESSAGES, "outcome WORD")))
        return self

    def _bound_socket(self, address: str | bytes) -> socket.socket:
        """A datagram socket bound to ``address`` that receives senders' credentials (OSError if not)."""
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        try:
            access.allow_credentials(sock)
            sock.bind(address)
            access.restrict(self.address)
        except OSError:
            sock.close()
            raise
        sock.settimeout(POLL_S)
        return sock

    def _bind_address(self) -> str | bytes:
        if problem := access.socket_path_problem(self.address):
            raise OSError(problem)
        if self.address.startswith("@"):
            return b"\0" + self.address[1:].encode()
        path = Path(self.address)
        if not path.exists():
            return self.address
        if access.held(self.address):
            raise OSError(access.in_use_line(self.address))
        path.unlink()  # left by an earlier run
        return self.address

    def _loop(self) -> None:
        while not self._stop.is_set() and (sock := self._sock) is not None:
            try:  # one byte more: a longer datagram is seen, not cut
                data, ancillary, _flags, _sender = sock.recvmsg(MAX_DATAGRAM + 1, access.ANCILLARY_BYTES)
            except TimeoutError:
                self._rebind_if_removed()
                continue
            except OSError:
                if self._stop.is_set():
                    return
                continue
            uid = access.sender_uid(ancillary)
            if not access.may_steer(uid):
                self._refuse(uid)
                continue
            self._handle(data)

    def _refuse(self, uid: int | None) -> None:
        self.refused += 1
        if self.refused == 1:
            log.warning("control socket %s: dropped a datagram from uid %s (only the daemon's user and root may "
                        "send robot messages); further ones are only counted", self.address, uid)

    def _rebind_if_removed(self) -> None:
        """A socket file deleted while running (tmp cleaner, a careless ``rm``) is bound again:
        otherwise every later robot message would be lost without a word. Another file put in its place
        is left alone (it is not ours) and said once; once it is gone, the socket is bound again."""
        if self.address.startswith("@"):
            return
        now = self._file_id()
        if now is not None:
            if now != self._bound and not self._replaced_said:
                self._replaced_said = True
                log.error("control socket %s was replaced by another file while running; robot messages do not "
                          "reach the daemon until that file is removed (then the socket is bound again)", self.address)
            return
        try:  # the folder checked again: its owner may have changed since
            sock = self._bound_socket(self._bind_address())
        except OSError as exc:
            if not self._rebind_failed:
                self._rebind_failed = True
                log.error("control socket %s was removed and cannot be bound again (%s); robot messages are "
                          "lost until it can", self.address, exc.strerror or exc)
            return
        old, self._sock, self._rebind_failed, self._replaced_said = self._sock, sock, False, False
        self._bound = self._file_id()
        if old is not None:
            old.close()
        log.warning("control socket %s was removed while running; bound it again", self.address)

    def _file_id(self) -> tuple[int, int] | None:
        """(device, inode) of whatever is at the socket's path now, None when nothing is."""
        try:
            st = os.lstat(self.address)
        except OSError:
            return None
        return st.st_dev, st.st_ino

    def _handle(self, data: bytes) -> None:
        message = parse_message(data)
        callbacks = {"grasp": self.on_grasp, "arm": self.on_arm, OUTCOME: self.on_outcome}
        callback = None if message is None else callbacks[message[0]]
        if message is None or callback is None:
            self.garbage += 1
            if self.garbage == 1:
                log.warning("control socket %s: ignored a datagram that is not one of %s or 'outcome WORD' (%r); "
                            "further ones are only counted", self.address, ", ".join(repr(m) for m in MESSAGES),
                            data[:64])
            return
        self.received += 1
        try:
            callback(message[1], "control")
        except Exception as exc:  # the callback must never end the reader
            log.error("control socket %s: %s", self.address, exc)

    def stop(self, timeout: float = 1.0) -> None:
        """End the reader, close and remove the socket file."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        if not self.address.startswith("@"):
            with contextlib.suppress(OSError):
                if stat.S_ISSOCK(os.lstat(self.address).st_mode) and self._file_id() == self._bound:
                    os.unlink(self.address)  # only our own socket: one put in its place belongs to someone else


class MessageLog:
    """At most one log line per ``GRASP_LOG_INTERVAL_S`` for each kind of robot message: a chatty robot
    (or a flood on the socket) must not flood the journal; the lines skipped are counted in the next."""

    def __init__(self) -> None:
        self._logged: dict[str, float] = {}
        self._unlogged: dict[str, int] = {}

    def note(self, kind: str, word: str, source: str) -> None:
        now = time.monotonic()
        if now - self._logged.get(kind, float("-inf")) < GRASP_LOG_INTERVAL_S:
            self._unlogged[kind] = self._unlogged.get(kind, 0) + 1
            return
        skipped = self._unlogged.pop(kind, 0)
        more = f"; {skipped} more {kind} messages since the last line" if skipped else ""
        self._logged[kind] = now
        daemon_log.info("%s %s%s%s", kind, word, f" (from {source})" if source else "", more)
