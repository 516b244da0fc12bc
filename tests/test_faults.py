"""Every fault ends in a log line and a recovery (issue 18): a device that streams garbage, a
hang while connecting, health after recovery, reloads that retry rejected models, rollbacks.

The garbage devices are real byte peers (a TCP listener, a pseudo-terminal) streaming 0xAA as a
wrong baud rate or another device on the line would; the models are toy graphs
(tests/tiny_models.py), the data the simulated hand's (synthetic).
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import socket
import threading
import time
import tty
from pathlib import Path

import pytest

from firmware_io.client import DSAClient
from runtime.config import config_from_dict
from runtime.daemon import Daemon
from runtime.retry_notes import QUIET
from tests.clocks import ManualClock
from tests.tiny_models import tiny_model_bytes, write_model

pytest.importorskip("onnx")
GARBAGE = b"\xaa" * 512


def _config(models: Path, url: str, **extra):
    data = {"device": {"url": url, "reconnect_min_s": 0.05, "reconnect_max_s": 0.2},
            "model": {"folder": str(models), "poll_interval_s": 0.05},
            "sinks": {"stdout": False}, "trigger": {"fraction": 0.02, "hysteresis": 0.01}}
    for key, value in extra.items():
        data.setdefault(key, {}).update(value)
    return config_from_dict(data)


def _run_until(daemon: Daemon, until, timeout: float) -> bool:
    """daemon.run() in this thread until ``until(daemon)`` holds or ``timeout`` passes; whether it held."""
    held = threading.Event()

    def watch():
        deadline = time.monotonic() + timeout
        try:
            while time.monotonic() < deadline:
                if until(daemon):
                    held.set()
                    break
                time.sleep(0.01)
        finally:  # a failing condition must still end the run
            daemon.request_stop()

    thread = threading.Thread(target=watch, daemon=True)
    thread.start()
    daemon.run()
    thread.join()
    return held.is_set()


class GarbageTcpPeer:
    """Accepts connections and streams 0xAA to each, ignoring whatever the host sends."""

    def __init__(self) -> None:
        self.server = socket.create_server(("127.0.0.1", 0))
        self.server.settimeout(0.1)
        self.url = f"tcp://127.0.0.1:{self.server.getsockname()[1]}"
        self.connections = 0
        self.bytes_sent = 0
        self._stop = threading.Event()
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        conn = None
        while not self._stop.is_set():
            try:
                new, _ = self.server.accept()
                if conn is not None:
                    conn.close()
                conn, self.connections = new, self.connections + 1
                conn.setblocking(False)
            except (TimeoutError, OSError):
                pass
            if conn is None:
                continue
            try:
                while not self._stop.is_set():
                    with_data = _drain(conn)
                    self.bytes_sent += conn.send(GARBAGE)
                    if not with_data:
                        time.sleep(0.002)
                    if _pending_accept(self.server):
                        break
            except (BlockingIOError, InterruptedError):
                time.sleep(0.002)
            except OSError:
                conn.close()
                conn = None

    def close(self) -> None:
        self._stop.set()
        self.server.close()


def _drain(conn: socket.socket) -> bool:
    try:
        return bool(conn.recv(65536))
    except BlockingIOError:
        return False


def _pending_accept(server: socket.socket) -> bool:
    import select

    try:
        return bool(select.select([server], [], [], 0)[0])
    except (OSError, ValueError):  # closed by the test
        return True


class GarbagePty:
    """A pseudo-terminal whose far end streams 0xAA (a wrong baud rate looks like this)."""

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.url = f"serial://{os.ttyname(self.slave)}"
        self._stop = threading.Event()
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        while not self._stop.is_set():
            with contextlib.suppress(OSError):
                os.read(self.master, 65536)
            with contextlib.suppress(OSError):
                os.write(self.master, GARBAGE)
            time.sleep(0.002)

    def close(self) -> None:
        self._stop.set()
        time.sleep(0.01)
        for fd in (self.master, self.slave):
            os.close(fd)


def _quick_client(url: str) -> DSAClient:
    """The real client with a shorter open bound (set as attributes: today's client has none)."""
    client = DSAClient(url, auto_reconnect=False, stop_timeout=0.5)
    client.open_timeout = 2.0
    return client


@pytest.fixture
def models(tmp_path) -> Path:
    """A folder with one toy model for the distal pads (it decides the first class)."""
    (tmp_path / "models").mkdir()
    return write_model(tmp_path / "models", "toy.onnx", tiny_model_bytes()).parent


@pytest.fixture(params=["tcp", "pty"])
def garbage_device(request):
    peer = GarbageTcpPeer() if request.param == "tcp" else GarbagePty()
    yield peer
    peer.close()


def test_client_open_against_garbage_ends_at_its_deadline(garbage_device):
    """A total deadline that arriving bytes do not extend; the message says what to check."""
    client = _quick_client(garbage_device.url)
    errors: list[BaseException] = []
    stop = threading.Event()

    def attempt():
        try:
            client.open(should_stop=stop.is_set)
        except BaseException as exc:
            errors.append(exc)

    t0 = time.monotonic()
    thread = threading.Thread(target=attempt, daemon=True)
    thread.start()
    thread.join(6.0)
    took = time.monotonic() - t0
    stop.set()  # a client without a deadline is still waiting: cancel it
    thread.join(2.0)
    client.close(stop_timeout=0.1)
    assert took < 4.0, f"open() still waiting after {took:.1f} s of garbage"
    text = str(errors[0])
    assert garbage_device.url in text and "baud rate" in text, text


def test_daemon_against_garbage_logs_reports_and_retries(models, garbage_device, caplog, tmp_path):
    """The daemon must not hang in open(): one line naming the URL and what to check, the health
    file showing the state and the error, and another attempt after the backoff."""
    health = tmp_path / "status.json"
    cfg = _config(models, garbage_device.url)
    from dataclasses import replace

    cfg = replace(cfg, health_file=str(health))
    factory_calls: list[str] = []

    def factory(url: str):
        factory_calls.append(url)
        return _quick_client(url)

    daemon = Daemon(cfg, client_factory=factory)
    caplog.set_level(logging.WARNING, logger="handover")
    seen: list[dict] = []

    def until(d: Daemon) -> bool:
        if health.exists():
            seen.append(json.loads(health.read_text()))
        return d.link.retry_notes.attempts >= 2 and d.health.device_state == "disconnected"

    held = _run_until(daemon, until, timeout=12)
    assert held, daemon.health.snapshot()
    lines = [r.getMessage() for r in caplog.records if garbage_device.url in r.getMessage()]
    assert lines and "baud rate" in lines[0] and "retrying" in lines[0], lines
    assert len(lines) == 1, lines  # the second attempt counted other bytes: the same failure, not logged again
    assert "baud rate" in daemon.health.last_error
    assert factory_calls
    states = {s["device_state"] for s in seen}
    assert "connecting" in states, states  # while the first attempt runs, not a frozen "starting"
    assert any(s["device_state"] == "disconnected" and "baud rate" in s["last_error"] for s in seen), seen[-1]


def test_default_client_has_a_bounded_open(garbage_device):
    """The daemon's own client (defaults) gives up on a garbage stream within its open bound."""
    from runtime.device_link import CONNECT_BOUND_S, default_client

    client = default_client(garbage_device.url)
    assert client.open_timeout + client.stop_timeout < CONNECT_BOUND_S


class HangingClient:
    """A client whose open never completes but keeps asking whether to stop (a real hang in a
    driver would look like this to the daemon): the watchdog must stop being fed."""

    def __init__(self, url: str) -> None:
        self.url = url

    def open(self, should_stop):
        from firmware_io.client import Cancelled

        while not should_stop():
            time.sleep(0.01)
        raise Cancelled("cancelled")

    def close(self, stop_timeout=None) -> None:
        pass


def test_watchdog_stops_being_fed_when_connecting_hangs(models, caplog):
    from runtime.sdnotify import Notifier

    pings: list[float] = []

    class Recorder(Notifier):
        def notify(self, *lines: str) -> bool:
            if "WATCHDOG=1" in lines:
                pings.append(time.monotonic())
            return True

    notifier = Recorder({"WATCHDOG_USEC": "100000"})  # ping every 50 ms while healthy
    daemon = Daemon(_config(models, "tcp://127.0.0.1:9"), notifier=notifier, client_factory=HangingClient)
    daemon.link.connect_bound_s = 0.5
    caplog.set_level(logging.ERROR, logger="handover")
    t0 = time.monotonic()
    _run_until(daemon, lambda d: time.monotonic() - t0 > 1.5, timeout=3)
    assert pings and pings[0] - t0 < 0.5  # fed at first
    late = [p for p in pings if p - t0 > 0.8]
    assert not late, f"watchdog still fed {late[-1] - t0:.2f} s into a hung connect"
    assert any("no longer feeding the watchdog" in r.getMessage() for r in caplog.records)
    assert "connecting has not completed" in daemon.health.last_error


def test_last_error_is_cleared_once_streaming_again(models, tmp_path):
    """Health tells the truth after a recovery: the error moves to the history."""
    from firmware_io.transports import DeviceUnavailable

    tries: list[int] = []

    def factory(url: str):
        tries.append(1)
        if len(tries) == 1:
            raise DeviceUnavailable(f"{url}: cannot connect: Connection refused")
        return DSAClient(url, auto_reconnect=False)

    daemon = Daemon(_config(models, "sim://?events=4&realtime=0"), client_factory=factory)
    assert _run_until(daemon, lambda d: d.health.frames_received > 10, timeout=20)
    snap = daemon.health.snapshot()
    assert snap["last_error"] == ""
    assert snap["last_error_at"] is not None
    assert "Connection refused" in snap["recent_errors"][0]["error"]


def test_sighup_with_a_changed_scene_retries_a_rejected_model(tmp_path):
    """issue 15 item 1 / issue 18 item 2: the model rejected under the old scene serves after
    the config is fixed and reloaded, without touching the file."""
    import dataclasses

    folder = tmp_path / "models"
    folder.mkdir()
    write_model(folder, "distal.onnx", tiny_model_bytes())  # pads 1, 3, 5
    cfg_path = tmp_path / "h.toml"
    text = (f'[device]\nurl = "sim://?events=4&realtime=1&speed=8"\n[model]\nfolder = "{folder}"\n'
            'poll_interval_s = 0.05\n[sinks]\nstdout = false\n[scene]\npads = "all"\n')
    cfg_path.write_text(text)
    from runtime.config import load_config

    daemon = Daemon(load_config(cfg_path))
    state = {"reloaded": False}

    def until(d: Daemon) -> bool:
        if not state["reloaded"] and d.health.models_rejected >= 1 and d.health.frames_received > 5:
            cfg_path.write_text(text.replace('pads = "all"', 'pads = "distal"'))
            d.request_reload()
            state["reloaded"] = True
        return state["reloaded"] and d.model is not None

    assert _run_until(daemon, until, timeout=20), daemon.health.snapshot()
    assert dataclasses.asdict(daemon.cfg.scene)["pads"] == "distal"
    assert daemon.health.model_id == daemon.model.model_id


def test_a_copy_with_an_old_mtime_arrives_as_old_and_a_touched_one_serves(tmp_path):
    """Arrival is the mtime: cp -p / rsync -a keep an old one, so such a copy does not displace the
    newer model (a no-op chmod must not either); ``touch`` makes it the newest, and it serves."""
    from runtime.model import load_model
    from runtime.model_watch import ModelWatcher

    folder = tmp_path / "models"
    folder.mkdir()
    w = ModelWatcher(folder, loader=lambda p: load_model(p, warm_up=False), poll_interval=0.05)
    write_model(folder, "v2.onnx", tiny_model_bytes(tag="v2"))
    assert w.poll(require_stable=False).path.name == "v2.onnx"
    old = tmp_path / "v1.onnx"
    write_model(tmp_path, "v1.onnx", tiny_model_bytes(tag="v1"), mtime=time.time() - 86400)
    os.system(f"cp -p {old} {folder}/v1.onnx")
    assert w.poll() is None and w.poll() is None  # seen twice: as old as it was, not loaded
    now = time.time() + 1
    os.utime(folder / "v1.onnx", (now, now))
    assert w.poll() is None  # first sighting
    model = w.poll()
    assert model is not None and model.path.name == "v1.onnx"
    # and a restart (or run --check) agrees
    fresh = ModelWatcher(folder, loader=lambda p: load_model(p, warm_up=False))
    assert fresh.poll(require_stable=False).path.name == "v1.onnx"


def test_sighup_between_a_trigger_and_its_window_loses_no_event(tmp_path, models):
    """A reload asked for while a window is pending waits for the decision (it rebuilt the hot
    path and dropped the pending window before)."""
    from runtime.config import load_config

    n_events = 4
    cfg_path = tmp_path / "h.toml"
    cfg_path.write_text(f'[device]\nurl = "sim://?events={n_events}&realtime=0&loop=0"\n[model]\nfolder = "{models}"\n'
                        'poll_interval_s = 0.05\n[sinks]\nstdout = false\n'
                        '[trigger]\nfraction = 0.02\nhysteresis = 0.01\nrefractory_s = 1.0\n')
    events: list = []
    reloads: list[int] = []

    class ReloadMidWindow(Daemon):
        def handle_frame(self, frame) -> None:
            had = len(self.detector.windows)
            super().handle_frame(frame)
            if len(self.detector.windows) > had:  # a trigger just fired: its window is still to come
                reloads.append(frame.number)
                self.request_reload()

    daemon = ReloadMidWindow(load_config(cfg_path), on_event=events.append)
    assert _run_until(daemon, lambda d: d.health.device_faults >= 1, timeout=30)  # the end of the session
    from firmware_io.emulator.frame_source import load_source

    trials = load_source("sim", seed=0, events=n_events).trials
    assert len(reloads) == len(trials)
    assert len(events) == len(trials), f"{len(events)} events for {len(trials)} triggers with a reload each"


def test_log_lines_carry_a_time_outside_journald():
    from runtime.commands.daemon_cli import log_format

    assert "%(asctime)s" in log_format({})
    assert "%(asctime)s" not in log_format({"JOURNAL_STREAM": "8:12345"})


def test_a_failure_that_counts_differently_each_time_is_the_same_failure():
    """A device sending nonsense fails every open with another byte count: one line, then rarely."""
    from runtime.retry_notes import RetryNotes

    clock = ManualClock(1000.0)
    notes = RetryNotes(clock=clock)
    lines = []
    for n in range(7):
        lines.append(notes.failed(f"open did not complete within 10 s although {31088640 - n * 4096} bytes arrived", 10.0))
        clock.t += 10.0
    assert lines[0].startswith("open did not complete") and lines[1:6] == [None] * 5
    assert lines[6].startswith("still unreachable after 7 attempts in 60 s (last: open did not complete within 10 s "
                               "although 31064064 bytes arrived)")
    assert notes.failed("cannot connect: Connection refused", 10.0).startswith("cannot connect")  # other words: at once
    assert notes.failed("bad reply to command 0x01 (CRC 0xBEEF)", 10.0)
    assert notes.failed("bad reply to command 0x01 (CRC 0x0C3A)", 10.0) is None  # another checksum, same failure


def test_a_device_that_alternates_two_ways_of_failing_is_one_outage():
    """A port that accepts and then closes, or resets, by turns: each reason once, then the 1/10/60 min
    rhythm (the attacker saw 7 warnings in 80 s)."""
    from runtime.retry_notes import RetryNotes

    clock = ManualClock(1000.0)
    notes = RetryNotes(clock=clock)
    reasons = ("tcp://h:1: the device closed the connection before any byte came", "tcp://h:1: "
               "connection lost: Connection reset by peer before any byte came")
    lines = []
    for n in range(13):
        lines.append(notes.failed(reasons[n % 2], 5.0))
        clock.t += 5.0
    assert [line is not None for line in lines] == [True, True] + [False] * 11
    # a minute after the latest new reason began
    assert notes.failed(reasons[1], 5.0).startswith("still unreachable after 14 attempts in 65 s")
    notes.connected()
    assert notes.failed(reasons[1], 5.0).startswith("tcp://h:1: connection lost")  # a new outage starts afresh


def test_a_refused_device_is_logged_once_then_rarely_while_health_hears_every_attempt(models, caplog):
    """Six identical warnings a minute forever buried the journal: now the first failure, the same one
    again 1, 10 and 60 minutes later (then hourly), a new reason at once, and one line when it is back."""
    from firmware_io.transports import DeviceUnavailable
    from runtime.retry_notes import RetryNotes

    state = {"reason": "cannot connect: Connection refused", "up": False}

    def factory(url: str):
        if state["up"]:
            return DSAClient(url, auto_reconnect=False)
        raise DeviceUnavailable(f"{url}: {state['reason']}")

    clock = ManualClock(1000.0)
    daemon = Daemon(_config(models, "sim://?events=4&realtime=0"), client_factory=factory)
    daemon.link.retry_notes = RetryNotes(clock=clock)
    caplog.set_level(logging.INFO, logger="handover.daemon")

    def attempts(n: int, every_s: float = 10.0) -> list[str]:
        caplog.clear()
        for _ in range(n):
            daemon.link.connect()
            assert state["up"] or daemon.health.last_error.endswith(state["reason"])  # current on every attempt
            clock.t += every_s
        return [r.getMessage() for r in caplog.records if r.name == "handover.daemon"]

    first = attempts(6 * 125)  # two hours and five minutes at the 10 s backoff
    assert len(first) == 5, first  # at once, after 1, 10, 60 and 120 minutes
    assert first[0] == f"device sim://?events=4&realtime=0: cannot connect: Connection refused; retrying in 0.1 s{QUIET}"
    assert first[1].startswith("device sim://?events=4&realtime=0: still unreachable after 7 attempts in 60 s "
                               "(last: cannot connect: Connection refused)")
    assert "after 61 attempts in 10 min" in first[2] and "after 361 attempts in 60 min" in first[3]
    assert "after 721 attempts in 2.0 h" in first[4]
    state["reason"] = "no answer within 3 s (hand powered? cable?)"
    changed = attempts(3)
    assert len(changed) == 1 and changed[0].endswith(f"no answer within 3 s (hand powered? cable?); retrying in 0.2 s{QUIET}")
    state["up"] = True
    back = attempts(1)
    daemon.link.close()
    daemon.link.client = None  # the next attempt asks the factory again
    assert len(back) == 1 and back[0].startswith("device sim://?events=4&realtime=0 connected after 753 failed "
                                                 "attempts in 2.1 h"), back
    assert daemon.health.last_error == ""
    state["up"] = False
    again = attempts(1)
    assert len(again) == 1 and again[0].endswith(f"no answer within 3 s (hand powered? cable?); retrying in 0.2 s{QUIET}")


def test_a_device_whose_every_frame_is_refused_says_so_at_the_stall(models, caplog):
    """CRC-valid frames with pressure on a cell the pad does not have, all of them: no frame reaches the
    daemon, and its stall line used to read like a silent device. It names the refused frames and why."""
    from firmware_io.emulator.device import DeviceEmulator
    from firmware_io.emulator.frame_source import load_source
    from firmware_io.recordings.recording import Recording
    from firmware_io.transports.emulated import EmulatedTransport

    rec = load_source("sim", seed=3, events=1)
    frames = rec.frames[:200].copy()
    frames[:, 84] = 700  # matrix 1 starts at 84; its cell (0, 0) does not exist
    nonsense = Recording(rec.layout, frames, rec.timestamps[:200])

    def factory(url: str):
        emulator = DeviceEmulator(nonsense, speed=1.0, loop=True)
        return DSAClient(EmulatedTransport(emulator), auto_reconnect=False, gap_timeout=0.3, stop_timeout=0.3,
                         flush_max=0.3)

    cfg = _config(models, "sim://?events=1", device={"stall_timeout_s": 0.5})
    daemon = Daemon(cfg, client_factory=factory)
    caplog.set_level(logging.WARNING, logger="handover")
    assert _run_until(daemon, lambda d: d.health.stalls >= 1, timeout=15)
    lines = [r.getMessage() for r in caplog.records if "refused" in r.getMessage()]
    assert lines and "no usable frame for 0.5 s" in lines[0] and "a cell the pad does not have" in lines[0], lines
    assert daemon.health.frames_received == 0
