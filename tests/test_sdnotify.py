"""sd_notify messages arrive on a socket the test provides (as systemd would)."""

from __future__ import annotations

import os
import socket

from runtime.sdnotify import Notifier
from tests.datagrams import abstract_listener


def _receive_all(sock: socket.socket) -> list[str]:
    out = []
    sock.setblocking(False)
    while True:
        try:
            out.append(sock.recv(4096).decode())
        except BlockingIOError:
            return out


def test_ready_status_watchdog_stopping(tmp_path):
    path = tmp_path / "notify.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(path))
    n = Notifier({"NOTIFY_SOCKET": str(path), "WATCHDOG_USEC": "2000000", "WATCHDOG_PID": str(os.getpid())})
    assert n.watchdog_interval == 1.0
    assert n.ready("serving")
    assert n.status("32 frames/s")
    assert n.watchdog(now=100.0)
    assert not n.watchdog(now=100.5)  # less than half the period since the last ping
    assert n.watchdog(now=101.1)
    assert n.stopping()
    msgs = _receive_all(sock)
    assert msgs == ["READY=1\nSTATUS=serving", "STATUS=32 frames/s", "WATCHDOG=1", "WATCHDOG=1", "STOPPING=1"]
    n.close()
    sock.close()


def test_abstract_namespace_socket():
    with abstract_listener("handover-notify") as (address, sock):
        n = Notifier({"NOTIFY_SOCKET": address})
        assert n.ready()
        assert _receive_all(sock) == ["READY=1"]


def test_without_systemd_everything_is_a_no_op():
    n = Notifier({})
    assert n.watchdog_interval is None
    assert not n.ready() and not n.watchdog() and not n.stopping()


def test_watchdog_for_another_pid_is_ignored():
    n = Notifier({"WATCHDOG_USEC": "1000000", "WATCHDOG_PID": "1"})
    assert n.watchdog_interval is None


def test_vanished_socket_is_not_fatal(tmp_path):
    n = Notifier({"NOTIFY_SOCKET": str(tmp_path / "gone.sock")})
    assert not n.ready()
    assert n.errors == 1
