"""The daemon end to end over the in-process simulated hand (sim://) and the TCP emulator.

The models are toy graphs (tests/tiny_models.py): they decide a fixed class, so these tests
check the plumbing (one decision per scripted event, model swap, refusal, reconnects,
signals), not accuracy. The data is the simulated hand's (synthetic).
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from firmware_io.emulator.frame_source import load_source
from firmware_io.transports.usb import FTDI_LATENCY_MS
from runtime.config import config_from_dict
from runtime.daemon import Daemon
from runtime.detector import Detector
from runtime.listeners import FrameRecorder
from runtime.sinks import Event
from tests.tiny_models import CLASSES, tiny_model_bytes, write_model
from tests.waiting import sigterm_seconds

pytest.importorskip("onnx")
ROOT = Path(__file__).resolve().parents[1]
N_EVENTS = 6
# The simulated hand presses lightly (synthetic); a low threshold makes every scripted event trigger.
TRIGGER = {"fraction": 0.02, "hysteresis": 0.01, "refractory_s": 1.0}


def _config(models: Path, url: str, **extra):
    data = {"device": {"url": url, "reconnect_min_s": 0.05, "reconnect_max_s": 0.2},
            "model": {"folder": str(models), "poll_interval_s": 0.05},
            "sinks": {"stdout": False}, "trigger": TRIGGER}
    for key, value in extra.items():
        data.setdefault(key, {}).update(value)
    return config_from_dict(data)


def _serve(daemon: Daemon, until, timeout: float = 30.0) -> None:
    """Run the daemon in a thread until ``until(daemon)`` holds; fail on timeout."""
    def watch():
        deadline = time.monotonic() + timeout
        while not until(daemon) and time.monotonic() < deadline:
            time.sleep(0.005)
        daemon.request_stop()

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    daemon.run()
    watcher.join()
    assert until(daemon), f"condition not reached within {timeout} s: {daemon.health.snapshot()}"


def _bias(cls: str) -> tuple[float, ...]:
    return tuple(1.0 if c == cls else 0.0 for c in CLASSES)


@pytest.fixture
def models(tmp_path) -> Path:
    folder = tmp_path / "models"
    folder.mkdir()
    write_model(folder, "first.onnx", tiny_model_bytes(bias=_bias("pull")), mtime=time.time() - 100)
    return folder


def _trials():
    return load_source("sim", seed=0, events=N_EVENTS).trials


def test_one_decision_per_scripted_event_over_sim(models):
    import gc

    events: list[Event] = []
    cfg = _config(models, f"sim://?events={N_EVENTS}&realtime=0&loop=0")
    daemon = Daemon(cfg, on_event=events.append)
    seen = FrameRecorder()
    daemon.listeners.append(seen)
    gc.unfreeze()
    try:
        _serve(daemon, lambda d: d.health.device_faults >= 1)  # the end of the session
        assert gc.get_freeze_count() > 0  # start-up's objects hidden from the collector (settle_heap)
    finally:
        gc.unfreeze()
    trials = _trials()
    assert len(events) == len(trials)
    for event, trial in zip(events, trials, strict=True):
        assert trial.first <= event.frame_first and event.frame_last <= trial.last
        assert event.frame_last - event.frame_first + 1 == 15
        assert event.cls == "pull" and event.latency_us > 0
    n = len(seen.frames)
    assert seen.frames == list(range(n))  # no frame lost
    assert daemon.health.frames_dropped == 0 and daemon.health.decisions == len(trials)
    p50, p99 = daemon.health.latency_p50_us, daemon.health.latency_p99_us
    print(f"\nsim:// synthetic session: {len(events)} events, latency p50 {p50:.0f} us p99 {p99:.0f} us")


def test_over_the_tcp_emulator_with_corrupted_frames(models):
    from firmware_io.emulator.device import DeviceEmulator, FaultPlan
    from firmware_io.emulator.server import TcpEmulatorServer

    rec = load_source("sim", seed=0, events=N_EVENTS)
    server = TcpEmulatorServer(DeviceEmulator(rec, speed=None, loop=False, faults=FaultPlan(crc=0.02))).start()
    events: list[Event] = []
    try:
        daemon = Daemon(_config(models, server.url), on_event=events.append)
        _serve(daemon, lambda d: d.health.frames_received >= rec.n_frames * 0.9 and d.health.device_faults >= 1)
    finally:
        server.stop()
    h = daemon.health
    assert h.crc_errors > 0  # counted, never fatal
    assert N_EVENTS - 2 <= len(events) <= N_EVENTS  # a corrupted frame may cost a trigger, never the daemon


def test_over_an_emulated_ftdi_bridge_unplugged_and_replugged(models):
    """usb:// through pyusb's real code to the emulated FTDI chip (latency timer 1 ms, a status packet
    every millisecond while idle): the bridge is pulled twice and plugged in again; the daemon
    reconnects each time and loses only the frame that was on the wire, with nothing garbled."""
    from firmware_io.client import DSAClient
    from firmware_io.emulator.device import DeviceEmulator, FaultPlan
    from firmware_io.emulator.links import EmulatedUsbBackend

    pytest.importorskip("usb")
    # replug power-cycles the controller: a 1 s boot (not the real 8 s) is the same deaf-then-answer path
    emulator = DeviceEmulator(load_source("sim", seed=0, events=N_EVENTS), faults=FaultPlan(disconnect_after=40),
                              boot_s=1.0, boot_query_s=0.5)
    backend = EmulatedUsbBackend(emulator)
    stop = threading.Event()

    def replug() -> None:
        while not stop.wait(0.01):
            if backend.unplugged:
                time.sleep(0.2)
                backend.replug()

    plugger = threading.Thread(target=replug, daemon=True)
    plugger.start()
    url = "usb://0403:6001"
    daemon = Daemon(_config(models, url),
                    client_factory=lambda u: DSAClient(u, auto_reconnect=False, transport_opts={"backend": backend}))
    try:
        _serve(daemon, lambda d: d.health.reconnects >= 2 and d.health.frames_received >= 100)
    finally:
        stop.set()
        plugger.join()
    h, sent = daemon.health, emulator.stats.frames_sent
    assert backend.latency_ms == FTDI_LATENCY_MS and emulator.stats.disconnects >= 2
    assert h.crc_errors == h.protocol_errors == h.frames_dropped == 0
    assert sent - emulator.stats.disconnects - 1 <= h.frames_received <= sent


def test_model_dropped_mid_stream_is_swapped_without_losing_a_frame(models):
    events: list[Event] = []

    def on_event(event: Event) -> None:
        events.append(event)
        if len(events) == 2:
            write_model(models, "second.onnx", tiny_model_bytes(bias=_bias("push")))
            deadline = time.monotonic() + 10  # hold the stream until the watcher thread has it ready
            while daemon.models.watcher.pending is None and time.monotonic() < deadline:
                time.sleep(0.01)

    daemon = Daemon(_config(models, f"sim://?events={N_EVENTS}&realtime=0&loop=0"), on_event=on_event)
    seen = FrameRecorder()
    daemon.listeners.append(seen)
    _serve(daemon, lambda d: d.health.device_faults >= 1)
    assert [e.cls for e in events] == ["pull", "pull"] + ["push"] * (N_EVENTS - 2)
    assert len({e.model_id for e in events[:2]}) == 1 and events[2].model_id != events[0].model_id
    assert seen.frames == list(range(len(seen.frames)))
    assert daemon.health.models_loaded == 2


def test_broken_model_dropped_mid_stream_is_refused_and_the_old_keeps_serving(models):
    events: list[Event] = []

    def on_event(event: Event) -> None:
        events.append(event)
        if len(events) == 2:
            data = tiny_model_bytes(bias=_bias("push"))
            write_model(models, "broken.onnx", data[: len(data) // 2], mtime=time.time() - 20)  # not being copied
            deadline = time.monotonic() + 10
            while not daemon.models.watcher.rejections and time.monotonic() < deadline:
                time.sleep(0.01)

    daemon = Daemon(_config(models, f"sim://?events={N_EVENTS}&realtime=0&loop=0"), on_event=on_event)
    _serve(daemon, lambda d: d.health.device_faults >= 1)
    assert [e.cls for e in events] == ["pull"] * N_EVENTS
    assert len({e.model_id for e in events}) == 1
    assert daemon.health.models_rejected == 1
    assert "broken.onnx" in daemon.health.last_error or daemon.models.watcher.rejections[0].path.name == "broken.onnx"


def test_unplug_and_replug_are_survived(models):
    events: list[Event] = []
    url = f"sim://?events={N_EVENTS}&realtime=0&loop=1&fault=disconnect=250"
    daemon = Daemon(_config(models, url), on_event=events.append)
    _serve(daemon, lambda d: d.health.reconnects >= 3 and d.health.frames_received > 1000)
    h = daemon.health
    assert h.device_faults >= 3 and h.device_state == "stopped"
    assert events and max(e.frame_last for e in events) > 750  # still deciding after three replugs


def test_no_model_means_no_inference_and_no_crash(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    daemon = Daemon(_config(empty, f"sim://?events={N_EVENTS}&realtime=0&loop=0"))
    _serve(daemon, lambda d: d.health.device_faults >= 1)
    assert daemon.health.frames_received > 500 and daemon.health.decisions == 0


def test_continuous_mode_reports_changes_of_a_dormant_model(tmp_path):
    folder = tmp_path / "models"
    folder.mkdir()
    classes = (*CLASSES, "idle")
    # scores: pull = mean(frames) (a touch), idle = 2 (nothing): a change of class is reported
    write_model(folder, "c.onnx", tiny_model_bytes(classes=classes, weights=(1.0, 0, 0, 0, 0),
                                                   bias=(0, -1, -1, -1, 2.0), dormant_class="idle"))
    events: list[Event] = []
    daemon = Daemon(_config(folder, f"sim://?events={N_EVENTS}&realtime=0&loop=0", scene={"mode": "continuous"}),
                    on_event=events.append)
    _serve(daemon, lambda d: d.health.device_faults >= 1)
    h = daemon.health
    assert h.decisions >= h.frames_received - 20  # every frame once the ring holds T frames
    assert 1 <= len(events) < h.decisions / 10  # reported on change only
    assert all(e.cls == "pull" for e in events)


def _notify_socket(tmp_path: Path) -> tuple[socket.socket, str]:
    path = str(tmp_path / "notify.sock")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(0.2)
    return sock, path


def _notified_run(cfg: Path, notify_socket: str, watchdog_usec: int) -> subprocess.Popen:
    """``handover run --config CFG`` as systemd starts it: a notify socket and a watchdog period."""
    env = {**os.environ, "NOTIFY_SOCKET": notify_socket, "WATCHDOG_USEC": str(watchdog_usec), "PYTHONPATH": str(ROOT)}
    return subprocess.Popen([sys.executable, "-m", "runtime.cli", "run", "--config", str(cfg)], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for(sock: socket.socket, needle: str, timeout: float, seen: list[str]) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            seen.append(sock.recv(4096).decode())
        except TimeoutError:
            continue
        if any(needle in m for m in seen):
            return True
    return False


def test_service_notify_reload_and_sigterm(models, tmp_path):
    """A real process: READY/STATUS/WATCHDOG/STOPPING on our socket, SIGHUP, SIGTERM within a second."""
    sock, path = _notify_socket(tmp_path)
    health = tmp_path / "status.json"
    cfg = tmp_path / "h.toml"
    text = (f'health_file = "{health}"\n[device]\nurl = "sim://?events={N_EVENTS}&speed=4"\n'
            f'[model]\nfolder = "{models}"\npoll_interval_s = 0.1\n'
            '[trigger]\nfraction = 0.02\nhysteresis = 0.01\n')
    cfg.write_text(text)
    proc = _notified_run(cfg, path, watchdog_usec=400000)
    seen: list[str] = []
    try:
        assert _wait_for(sock, "READY=1", 30, seen), seen
        assert _wait_for(sock, "WATCHDOG=1", 5, seen), seen
        assert _wait_for(sock, "frames/s", 5, seen), seen
        # an invalid config on SIGHUP is refused and the daemon keeps running
        cfg.write_text(text.replace("fraction = 0.02", "fraction = 7"))
        proc.send_signal(signal.SIGHUP)
        after: list[str] = []
        assert _wait_for(sock, "RELOADING=1", 5, after), after
        assert _wait_for(sock, "READY=1", 5, after), after
        time.sleep(0.3)
        assert proc.poll() is None
        # a valid one is taken
        cfg.write_text(text)
        proc.send_signal(signal.SIGHUP)
        time.sleep(0.5)
        stop_s = sigterm_seconds(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
        out, err = proc.communicate()
    assert proc.returncode == 0, err
    assert _wait_for(sock, "STOPPING=1", 1, seen), seen
    assert "trigger.fraction" in err and "keeping the running configuration" in err
    assert "configuration reloaded" in err
    assert "Traceback" not in err
    status = json.loads(health.read_text())
    assert status["device_state"] == "stopped" and status["model_id"]
    lines = [json.loads(line) for line in out.splitlines()]  # stdout carries only JSON events
    assert lines[0]["type"] == "model" and {d["type"] for d in lines} <= {"decision", "model"}
    assert all(d["class"] in CLASSES for d in lines if d["type"] == "decision")
    print(f"\nSIGTERM -> exit in {stop_s * 1000:.0f} ms")
    assert stop_s < 1.0
    sock.close()


# -- review fixes (issue 6) ---------------------------------------------------------------------


def test_end_to_end_over_a_pseudo_terminal(models):
    """serial://<pty> to the emulator, as a USB-serial adapter would be reached."""
    from firmware_io.emulator.device import DeviceEmulator
    from firmware_io.emulator.server import EmulatorServerError, PtyEmulatorServer

    rec = load_source("sim", seed=0, events=N_EVENTS)
    try:
        server = PtyEmulatorServer(DeviceEmulator(rec, speed=None, loop=False)).start()
    except EmulatorServerError as exc:
        pytest.skip(f"no pseudo-terminal here: {exc}")
    events: list[Event] = []
    try:
        daemon = Daemon(_config(models, server.url, device={"stall_timeout_s": 0.5}), on_event=events.append)
        seen = FrameRecorder()
        daemon.listeners.append(seen)
        _serve(daemon, lambda d: d.health.frames_received >= rec.n_frames)
    finally:
        server.stop()
    trials = rec.trials
    assert len(events) == len(trials)
    for event, trial in zip(events, trials, strict=True):
        assert trial.first <= event.frame_first and event.frame_last <= trial.last and event.cls == "pull"
    assert seen.frames == list(range(len(seen.frames)))  # no frame lost
    assert daemon.health.crc_errors == 0 and daemon.health.frames_dropped == 0


def _level_frames(levels: list[int], column: int, n_taxels: int, period_ms: float = 31.25):
    from firmware_io.client import Frame

    for i, level in enumerate(levels):
        values = np.zeros(n_taxels, dtype=np.uint16)
        values[column] = level
        yield Frame(i, round(i * period_ms), time.perf_counter(), values)


def test_default_trigger_reports_a_wobbling_interaction_once(models):
    """Synthetic levels: a push crosses the trigger level, its pressure dips below the re-arm level
    for 4 frames 0.6 s later and crosses again; a second push follows 4 s later. Two events."""
    from firmware_io.layout import SensorLayout
    from runtime.model import load_model

    layout = SensorLayout.sdh2()
    on, dip = 800, 300  # trigger at 0.15 x 4095 = 614, re-arm below 0.10 x 4095 = 410
    push = [on] * 20 + [dip] * 4 + [on] * 20 + [0] * 10
    levels = [0] * 20 + push + [0] * 70 + push + [0] * 40
    detector = Detector()
    detector.swap(load_model(models / "first.onnx"), layout)
    frames = _level_frames(levels, int(layout.columns("distal")[40]), layout.n_taxels)
    decisions = [d for d in map(detector.feed, frames) if d is not None]
    assert detector.trigger.fired == 2 and len(decisions) == 2
    assert [d.first for d in decisions] == [20, 20 + len(push) + 70]


def _silent_tcp_peer():
    """A TCP listener that accepts and never answers (a hung controller, a wrong host:port)."""
    server = socket.create_server(("127.0.0.1", 0))
    accepted: list[socket.socket] = []

    def accept():
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            accepted.append(conn)

    threading.Thread(target=accept, daemon=True).start()
    return server, accepted


def test_sigterm_while_connecting_to_a_silent_device(models, tmp_path):
    """Opening a silent device takes seconds of bounded retries; SIGTERM must still end the
    process within a second, and the watchdog keeps being fed meanwhile."""
    server, accepted = _silent_tcp_peer()
    sock, path = _notify_socket(tmp_path)
    cfg = tmp_path / "h.toml"
    cfg.write_text(f'[device]\nurl = "tcp://127.0.0.1:{server.getsockname()[1]}"\n[model]\nfolder = "{models}"\n')
    proc = _notified_run(cfg, path, watchdog_usec=200000)
    seen: list[str] = []
    try:
        assert _wait_for(sock, "READY=1", 30, seen), seen
        deadline = time.monotonic() + 10
        while not accepted and time.monotonic() < deadline:
            time.sleep(0.01)
        assert accepted, "the daemon never connected"
        during: list[str] = []
        assert _wait_for(sock, "WATCHDOG=1", 1.0, during), during  # fed while the open waits
        time.sleep(0.5)  # well inside the open's stop retries (1 s gap timeout each)
        stop_s = sigterm_seconds(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
        _out, err = proc.communicate()
        server.close()
        sock.close()
    print(f"\nSIGTERM while opening a silent device -> exit in {stop_s * 1000:.0f} ms")
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    assert stop_s < 1.5  # correctness bound (the issue asks < 1 s; slack for a busy machine)


def _run_bounded(daemon: Daemon, timeout: float = 10.0) -> int:
    """daemon.run(), stopped after ``timeout`` s if it does not end by itself (a regression)."""
    timer = threading.Timer(timeout, daemon.request_stop)
    timer.start()
    try:
        return daemon.run()
    finally:
        timer.cancel()


def test_a_url_that_can_never_open_is_fatal_not_retried(models):
    from dataclasses import replace

    from runtime.config import DeviceConfig

    cfg = _config(models, "sim://")
    daemon = Daemon(replace(cfg, device=DeviceConfig(url="foo://x")))  # past the config check
    assert _run_bounded(daemon) == 2
    assert daemon.fatal.startswith("device.url: foo://x: unknown scheme") and "\n" not in daemon.fatal
    assert daemon.health.device_state == "failed"


def test_a_missing_transport_package_is_fatal(models):
    from firmware_io.transports import MissingDependency

    def factory(url: str):
        raise MissingDependency(f"{url}: needs the Python package hidapi (pip install 'tactile-handover[usb]')")

    daemon = Daemon(_config(models, "hid://10c4:ea80"), client_factory=factory)
    assert _run_bounded(daemon) == 2
    assert "hidapi" in daemon.fatal


def test_an_absent_device_is_retried_not_fatal(models):
    from firmware_io.transports import DeviceUnavailable

    tries: list[str] = []

    def factory(url: str):
        tries.append(url)
        raise DeviceUnavailable(f"{url}: cannot open serial port: no such file")

    daemon = Daemon(_config(models, "serial:///dev/ttyNOPE"), client_factory=factory)
    _serve(daemon, lambda d: len(tries) >= 3, timeout=10)
    assert daemon.fatal is None and daemon.health.device_state != "failed"


def test_only_the_daemon_changes_its_detector():
    """The model slot swapped models into the detector, the link fitted it through the daemon's callback
    and a reload set ``detector.layout = None``: now ``Daemon._apply`` is the one place in the service."""
    import inspect
    import re

    from runtime.model_serving import ModelSlot

    assert "detector" not in inspect.signature(ModelSlot).parameters
    changes = re.compile(r"detector\.(?:swap|fit|configure)\(|detector\.layout\s*=(?!=)")
    found = {p.name: len(changes.findall(p.read_text())) for p in (ROOT / "runtime").glob("*.py")}
    assert {name: n for name, n in found.items() if n} == {"daemon.py": 3}
    source = inspect.getsource(Daemon._apply)
    assert all(f"detector.{verb}(" in source for verb in ("swap", "fit", "configure"))
