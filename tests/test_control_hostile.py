"""Hostile input on the daemon's control socket: oversized datagrams, a second daemon on the
same path, the socket file removed while the daemon runs."""

from __future__ import annotations

import functools
import logging
import os
import re
import socket
import threading
from pathlib import Path

import pytest

from runtime.control import MAX_DATAGRAM, POLL_S, ControlSocket
from tests.waiting import wait_for

_wait = functools.partial(wait_for, timeout=3.0)


@pytest.fixture
def sender():
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    yield sock
    sock.close()


def test_a_datagram_longer_than_the_limit_is_garbage_even_if_it_starts_with_a_message(tmp_path, sender):
    got: list[bool] = []
    path = str(tmp_path / "c.sock")
    control = ControlSocket(path, lambda closed, source: got.append(closed)).start()
    try:
        sender.sendto(b"grasp closed" + b" " * MAX_DATAGRAM + b"and then something else", path)
        sender.sendto(b"grasp open", path)
        assert _wait(lambda: control.garbage + control.received == 2)
        assert got == [False] and control.garbage == 1
    finally:
        control.stop()


def test_a_live_socket_of_another_daemon_is_not_taken_over(tmp_path, sender):
    path = str(tmp_path / "c.sock")
    first: list[bool] = []
    running = ControlSocket(path, lambda closed, source: first.append(closed)).start()
    try:
        with pytest.raises(OSError, match="in use by another process"):
            ControlSocket(path, lambda closed, source: None).start()
        sender.sendto(b"grasp closed", path)
        assert _wait(lambda: first == [True])
    finally:
        running.stop()


def test_a_socket_removed_while_running_is_bound_again_with_one_line(tmp_path, sender, caplog):
    got: list[bool] = []
    path = str(tmp_path / "c.sock")
    control = ControlSocket(path, lambda closed, source: got.append(closed)).start()
    try:
        with caplog.at_level(logging.WARNING, logger="handover.control"):
            os.unlink(path)
            assert _wait(lambda: Path(path).is_socket(), timeout=10 * POLL_S)
        sender.sendto(b"grasp closed", path)
        assert _wait(lambda: got == [True])
        lines = [r.getMessage() for r in caplog.records
                     if r.levelno >= logging.WARNING and "removed while running" in r.getMessage()]
        assert len(lines) == 1 and path in lines[0]
    finally:
        control.stop()
    assert not Path(path).exists()


@pytest.mark.parametrize("kind", ["file", "folder"])
def test_a_path_that_is_a_file_or_folder_is_left_alone_with_one_line_saying_so(tmp_path, kind):
    path = tmp_path / "c.sock"
    path.mkdir() if kind == "folder" else path.write_text("keep me")
    with pytest.raises(OSError, match=r"exists and is not a socket \(a (file|folder)\); remove it or choose another path"):
        ControlSocket(str(path), lambda closed, source: None).start()
    assert path.is_dir() if kind == "folder" else path.read_text() == "keep me"


def _abstract(tag: str) -> str:
    return f"@handover-test-{tag}-{os.getpid()}"


def _write_config(config: Path, tmp_path: Path, address: str, settle: float = 0.5) -> Path:
    config.write_text(f'[device]\nurl = "sim://"\n[sinks]\nstdout = false\n[model]\nfolder = "{tmp_path}"\n'
                      f'[control]\nsocket = "{address}"\narm_settle_s = {settle}\n')
    return config


def test_an_abstract_name_another_process_holds_fails_check_and_run_in_one_line(tmp_path, sender, capsys):
    """Another local user bound the name first: --check said rc 0 and the daemon ran deaf to ``grasp open``."""
    from runtime.cli import main

    address = _abstract("squatted")
    sender.bind(b"\0" + address[1:].encode())
    config = _write_config(tmp_path / "h.toml", tmp_path, address)
    for args in (["--check"], []):
        assert main(["run", *args, "--config", str(config)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"control.socket {address}: in use by another process" in err[0], err


def _daemon(config: Path):
    from runtime.config import load_config
    from runtime.daemon import Daemon

    daemon = Daemon(load_config(config))
    daemon.start_control()
    return daemon


def test_a_reload_that_keeps_the_address_never_lets_go_of_the_name(tmp_path):
    """A SIGHUP changing another [control] key closed the socket and bound it again: a process looping
    on bind won the name."""
    address = _abstract("kept")
    config = _write_config(tmp_path / "h.toml", tmp_path, address)
    daemon = _daemon(config)
    running, won, done = daemon.control, [], threading.Event()

    def squat() -> None:
        while not done.is_set():
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
            try:
                sock.bind(b"\0" + address[1:].encode())
                won.append(True)
                return
            except OSError:
                pass
            finally:
                sock.close()

    thread = threading.Thread(target=squat)
    thread.start()
    try:
        _write_config(config, tmp_path, address, settle=1.0)
        daemon.reload()
        assert daemon.cfg.control.arm_settle_s == 1.0 and daemon.control is running
    finally:
        done.set()
        thread.join()
        daemon.stop_control()
        daemon.sinks.close()
    assert not won


def test_a_reload_binds_the_new_socket_before_it_closes_the_old_and_a_held_one_keeps_the_running(
        tmp_path, sender, caplog):
    from runtime import control_access

    old, new, held = _abstract("old"), _abstract("new"), _abstract("held")
    config = _write_config(tmp_path / "h.toml", tmp_path, old)
    daemon = _daemon(config)
    running = daemon.control
    try:
        sender.bind(b"\0" + held[1:].encode())
        _write_config(config, tmp_path, held)
        with caplog.at_level(logging.ERROR, logger="handover.daemon"):
            daemon.reload()
        assert daemon.control is running and daemon.cfg.control.socket == old
        assert f"SIGHUP: control.socket {held}: in use by another process" in caplog.text
        seen: list[bool] = []
        stop = running.stop
        running.stop = lambda *a: (seen.append(control_access.held(new)), stop(*a))
        _write_config(config, tmp_path, new)
        daemon.reload()
        assert seen == [True] and daemon.control.address == new and not control_access.held(old)
    finally:
        daemon.stop_control()
        daemon.sinks.close()


@pytest.mark.parametrize("planted", ["owned_by_another_user", "others_may_write"])
def test_a_socket_folder_another_user_could_swap_it_in_is_refused_by_check_run_and_reload(
        tmp_path, capsys, caplog, planted):
    """uid 65534 owned the socket's folder: --check said 0, the daemon ran, and they unlinked its socket
    and bound their own, so the robot's ``arm moving`` reached them; a SIGHUP onto it was taken too."""
    from runtime.cli import main

    if planted == "owned_by_another_user" and os.geteuid() != 0:
        pytest.skip("giving a folder to another user needs root")
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    os.chown(theirs, 65534, 65534) if planted == "owned_by_another_user" else theirs.chmod(0o777)
    why = "owned by uid 65534" if planted == "owned_by_another_user" else "writable by others"
    address = str(theirs / "ctl.sock")
    config = _write_config(tmp_path / "h.toml", tmp_path, address)
    for args in (["--check"], []):
        assert main(["run", *args, "--config", str(config)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"control.socket {address}: folder {theirs} is {why}" in err[0], err
    assert not os.path.lexists(address)
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o1777)  # like /tmp: sticky, so only the socket's owner may remove it
    daemon = _daemon(_write_config(config, tmp_path, str(shared / "ctl.sock")))
    running = daemon.control
    try:
        _write_config(config, tmp_path, address)
        with caplog.at_level(logging.ERROR, logger="handover.daemon"):
            daemon.reload()
        assert daemon.control is running and daemon.cfg.control.socket == str(shared / "ctl.sock")
        assert f"SIGHUP: control.socket {address}: folder {theirs} is {why}" in caplog.text
    finally:
        daemon.stop_control()
        daemon.sinks.close()


def test_a_flood_of_grasp_messages_is_a_few_log_lines_not_one_per_message(tmp_path, caplog):
    from runtime.config import config_from_dict
    from runtime.daemon import Daemon

    daemon = Daemon(config_from_dict({"device": {"url": "sim://"}, "sinks": {"stdout": False},
                                      "model": {"folder": str(tmp_path)}}))
    with caplog.at_level(logging.INFO, logger="handover.daemon"):
        for i in range(5000):
            daemon.robot.set_grasp(i % 3 != 0, source="control")
    lines = [r.getMessage() for r in caplog.records if r.getMessage().startswith("grasp ")]
    assert 1 <= len(lines) <= 3, len(lines)
    assert daemon.detector.grasp_request == (True, "control") and len(daemon.detector._grasp) > 0


@pytest.mark.parametrize("key", ["control.socket", "sinks.unix", "health_file", "model.folder", "model.quarantine_file"])
def test_a_path_with_a_nul_character_is_a_config_error(key):
    """TOML's "\\u0000" passed --check, then ``handover run`` died of 'ValueError: embedded null byte'."""
    from runtime.config import ConfigError, config_from_dict

    section, _, name = key.rpartition(".")
    value = ["/tmp/a\x00b"] if key == "sinks.unix" else "/tmp/a\x00b"
    table = {section: {name: value}} if section else {name: value}
    with pytest.raises(ConfigError, match=re.escape(f"{key}: must not contain a control character ('\\x00')")):
        config_from_dict({"device": {"url": "sim://"}, **table})


def test_a_file_put_in_the_sockets_place_is_said_once_left_alone_and_the_socket_comes_back_after_it(
        tmp_path, sender, caplog):
    got: list[bool] = []
    path = str(tmp_path / "c.sock")
    control = ControlSocket(path, lambda closed, source: got.append(closed)).start()
    try:
        with caplog.at_level(logging.WARNING, logger="handover.control"):
            (tmp_path / "other").write_text("not a socket")
            os.replace(tmp_path / "other", path)  # in one step: the path is never seen missing
            assert _wait(lambda: any("replaced by another file" in r.getMessage() for r in caplog.records),
                         timeout=10 * POLL_S)
            assert Path(path).read_text() == "not a socket"
            os.unlink(path)
            assert _wait(lambda: Path(path).is_socket(), timeout=10 * POLL_S)
        sender.sendto(b"grasp closed", path)
        assert _wait(lambda: got == [True])
        said = [r.getMessage() for r in caplog.records if "replaced by another file" in r.getMessage()]
        assert len(said) == 1 and path in said[0]
    finally:
        control.stop()
    assert not Path(path).exists()


@pytest.mark.parametrize("address", ["@", "@  "])
def test_an_abstract_socket_with_no_name_is_refused_in_one_line_by_check_and_daemon(tmp_path, capsys, address):
    """``@`` alone bound the empty abstract name: a socket no robot is told about, shared by every
    daemon configured so."""
    from runtime.cli import main

    config = tmp_path / "h.toml"
    config.write_text(f'[device]\nurl = "sim://"\n[model]\nfolder = "{tmp_path}"\n[control]\nsocket = "{address}"\n')
    assert main(["run", "--check", "--config", str(config)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "an abstract socket needs a name after the @" in err[0], err
    with pytest.raises(OSError, match=r"needs a name after the @ \(e\.g\. @handover-control\); or use a path"):
        ControlSocket(address, lambda closed, source: None).start()


def test_an_abstract_name_another_process_holds_says_what_to_do(sender):
    address = f"@handover-test-held-{os.getpid()}"
    sender.bind(b"\0" + address[1:].encode())  # any local user may take an abstract name first
    with pytest.raises(OSError, match=r"in use by another process .*choose another name or a path"):
        ControlSocket(address, lambda closed, source: None).start()
