"""Serve a DeviceEmulator over a loopback TCP socket or a pseudo-terminal, in a background thread.

The TCP server listens on loopback only: the emulator is a test and demo device and must
never be reachable from the robot's network. The pseudo-terminal server opens a pty in raw
mode and keeps its own handle on the slave side, so pyserial can open and close the printed
path like a real port as often as it likes.
"""

from __future__ import annotations

import contextlib
import errno
import ipaddress
import logging
import os
import select
import socket
import termios
import threading
import time
import tty

from firmware_io.emulator.device import DeviceEmulator
from firmware_io.errors import HandoverError

__all__ = ["EmulatorServerError", "PtyEmulatorServer", "TcpEmulatorServer", "log"]

POLL_S = 0.05  # longest wait before the loop looks at the stop flag again
BAUD_CHECK_S = 0.1
"""How often the pty server reads the baud rate the host set."""
CHUNK = 65536
REFUSAL_NOTE_S = 10.0
"""Refused connections are logged at most once per this long (a retrying host is refused again and again)."""

log = logging.getLogger("handover.emulator")


class EmulatorServerError(HandoverError, OSError):
    """The server cannot start (address in use, not loopback, no pty support)."""


class _ServerBase:
    """Start/stop plumbing shared by both servers."""

    def __init__(self, emulator: DeviceEmulator) -> None:
        self.emulator = emulator
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: BaseException | None = None

    def start(self) -> _ServerBase:
        self._thread = threading.Thread(target=self._run_guarded, name=type(self).__name__, daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        self._close()

    def _run_guarded(self) -> None:
        try:
            self._run()
        except BaseException as exc:  # recorded for the owner; a server thread must not vanish silently
            self.error = exc
            if not isinstance(exc, Exception):
                raise

    def __enter__(self) -> _ServerBase:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _run(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _close(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _wait_time(self) -> float:
        wait = self.emulator.seconds_until_output()
        return POLL_S if wait is None else min(max(wait, 0.0), POLL_S)


class TcpEmulatorServer(_ServerBase):
    """One host at a time on ``tcp://127.0.0.1:PORT``, like a controller serving one host: while a host
    is connected, another connection is closed at once (and logged, naming the refused peer). When the
    host's connection ends, the controller power-cycles (``DeviceEmulator.power_cycle``), as an SDH-2
    resets behind Ethernet: push mode off, only persistent settings kept, booting again."""

    def __init__(self, emulator: DeviceEmulator, host: str = "127.0.0.1", port: int = 0) -> None:
        super().__init__(emulator)
        bare = host[1:-1] if host.startswith("[") and host.endswith("]") else host
        try:
            addr = ipaddress.ip_address(bare if ":" in bare else socket.gethostbyname(bare))
        except (OSError, ValueError):
            raise EmulatorServerError(f"cannot resolve listen address {host!r}") from None
        if not addr.is_loopback:
            raise EmulatorServerError(f"the emulator listens on loopback only (127.0.0.1 or ::1), not {host!r}")
        self.host = str(addr)
        family = socket.AF_INET6 if addr.version == 6 else socket.AF_INET
        self._listener = socket.socket(family, socket.SOCK_STREAM)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self._listener.bind((self.host, port))
        except OSError as exc:
            self._listener.close()
            hint = ("; another program (another emulator?) has it: give another port, or port 0 to pick a free one "
                    "(the emulator prints the URL it listens on)" if exc.errno == errno.EADDRINUSE else "")
            raise EmulatorServerError(f"cannot listen on {self.host}:{port}: {exc.strerror or exc}{hint}") from None
        self._listener.listen(2)
        self._listener.setblocking(False)
        self.port = self._listener.getsockname()[1]
        self._conn: socket.socket | None = None
        self.refused = 0
        """Connections closed at once because a host was connected."""
        self._refusals_unlogged = 0
        self._next_refusal_note = 0.0

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"tcp://{host}:{self.port}"

    def _run(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self._listener], [], [], POLL_S)
            if ready:
                self._accept()
            while self._conn is not None and not self._stop.is_set():
                self._session_step()

    def _accept(self) -> None:
        try:
            conn, peer = self._listener.accept()
        except (BlockingIOError, OSError):
            return
        if self._conn is not None and self._conn_closed_by_host():
            self._drop_conn()  # the host closed and came back before the loop saw it go
        if self._conn is not None:
            self._refuse(conn, peer)
            return
        conn.setblocking(False)
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._conn = conn
        self._pending = b""
        self.emulator.connect()

    def _conn_closed_by_host(self) -> bool:
        """The served host has closed its end (or the socket failed), without consuming its bytes."""
        try:
            return self._conn.recv(1, socket.MSG_PEEK) == b""
        except BlockingIOError:
            return False
        except OSError:
            return True

    def _refuse(self, conn: socket.socket, peer: object) -> None:
        """A second host while one is served: closed at once; one log line per ``REFUSAL_NOTE_S``."""
        with contextlib.suppress(OSError):
            conn.close()
        self.refused += 1
        self._refusals_unlogged += 1
        now = time.monotonic()
        if now < self._next_refusal_note:
            return
        self._next_refusal_note = now + REFUSAL_NOTE_S
        where = ":".join(str(p) for p in peer[:2]) if isinstance(peer, tuple) else str(peer)
        more = f" ({self._refusals_unlogged} refused since the last note)" if self._refusals_unlogged > 1 else ""
        self._refusals_unlogged = 0
        log.warning("refused a connection from %s: another host is connected (the emulated controller serves "
                    "one host at a time)%s", where, more)

    def _drop_conn(self) -> None:
        if self._conn is not None:
            with contextlib.suppress(OSError):
                self._conn.close()
            self._conn = None
            self._pending = b""
            if not self.emulator.booting:  # a host that gives up on a booting controller does not restart its boot
                self.emulator.power_cycle()

    def _session_step(self) -> None:
        conn = self._conn
        assert conn is not None
        wlist = [conn] if self._pending else []
        readable, _writable, _ = select.select([conn, self._listener], wlist, [], self._wait_time())
        if self._listener in readable:
            self._accept()
            return
        if conn in readable:
            try:
                data = conn.recv(CHUNK)
            except OSError:
                data = b""
            if not data:  # host closed the connection
                self._drop_conn()
                return
            self.emulator.feed(data)
        if not self._pending:
            self._pending = self.emulator.read(CHUNK)
        if self._pending:
            try:
                sent = conn.send(self._pending)
                self._pending = self._pending[sent:]
            except BlockingIOError:
                pass
            except OSError:
                self._drop_conn()
                return
        if self.emulator.disconnected and not self._pending:
            self._drop_conn()  # the fault plan pulled the plug

    def _close(self) -> None:
        self._drop_conn()
        with contextlib.suppress(OSError):
            self._listener.close()


class PtyEmulatorServer(_ServerBase):
    """The emulator behind a pseudo-terminal; ``path`` is what a client opens (``/dev/pts/N``).

    A pty cannot be unplugged, so the ``disconnect`` fault is a power cycle (``DeviceEmulator.power_cycle``).
    Bytes go out at the baud rate the host set, as a serial line carries them, not at memory speed.
    """

    def __init__(self, emulator: DeviceEmulator) -> None:
        super().__init__(emulator)
        try:
            self._master, self._slave = os.openpty()
        except OSError as exc:
            raise EmulatorServerError(f"cannot open a pseudo-terminal: {exc.strerror}") from None
        tty.setraw(self._slave)  # no echo, no line editing: bytes pass unchanged
        os.set_blocking(self._master, False)
        self.path = os.ttyname(self._slave)
        self._pending = b""
        self.baud: int | None = None
        """The baud rate the host set on the line (None until read)."""
        self._baud_checked = 0.0
        self.emulator.connect()

    def _follow_baud(self) -> None:
        """The host's baud rate, read from the terminal settings both ends share (a few times a second)."""
        now = time.monotonic()
        if now - self._baud_checked < BAUD_CHECK_S:
            return
        self._baud_checked = now
        try:
            speed = termios.tcgetattr(self._slave)[5]  # ospeed: the termios constant, e.g. B115200
        except (termios.error, OSError):
            return
        baud = _BAUDS.get(speed)
        if baud != self.baud:
            self.baud = baud
            self.emulator.set_line_rate(baud / 10.0 if baud else None)

    @property
    def url(self) -> str:
        return f"serial://{self.path}"

    def _run(self) -> None:
        while not self._stop.is_set():
            self._follow_baud()
            wlist = [self._master] if self._pending else []
            readable, _writable, _ = select.select([self._master], wlist, [], self._wait_time())
            if readable:
                try:
                    data = os.read(self._master, CHUNK)
                except BlockingIOError:
                    data = b""
                except OSError as exc:
                    if exc.errno == errno.EIO:
                        data = b""
                    else:
                        raise
                if data:
                    self.emulator.feed(data)
            if not self._pending:
                self._pending = self.emulator.read(CHUNK)
            if self._pending:
                try:
                    sent = os.write(self._master, self._pending)
                    self._pending = self._pending[sent:]
                except BlockingIOError:
                    pass
            if self.emulator.disconnected:  # unplugged and replugged: in-flight bytes lost, push mode off
                self._pending = b""
                self.emulator.power_cycle()

    def _close(self) -> None:
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)
        self._master = self._slave = -1


_BAUDS = {getattr(termios, f"B{b}"): b for b in (
    300, 600, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 576000, 921600,
    1000000, 1152000, 1500000, 2000000, 3000000, 4000000) if hasattr(termios, f"B{b}")}
"""termios speed constants -> baud."""
