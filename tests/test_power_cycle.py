"""A controller power cycle on a serial link (the emulator's, over a pseudo-terminal: silent for 8 s,
ESC[5n at 7 s, push mode off when it is back): the daemon and ``handover dump`` both read frames
again soon after the controller's return, without anyone restarting them. Real processes, the real
emulator, real boot times; slow."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from firmware_io.emulator.device import DeviceEmulator, FaultPlan
from firmware_io.emulator.frame_source import load_source
from firmware_io.emulator.server import EmulatorServerError, PtyEmulatorServer
from tests.ros2_helpers import TRIGGER
from tests.tiny_models import tiny_model_bytes, write_model

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[1]
RECOVER_S = 15.0


class Lines:
    """A process's stdout lines with the monotonic time each arrived."""

    def __init__(self, proc: subprocess.Popen) -> None:
        self.got: list[tuple[float, str]] = []
        threading.Thread(target=self._read, args=(proc,), daemon=True).start()

    def _read(self, proc: subprocess.Popen) -> None:
        for line in proc.stdout:
            self.got.append((time.monotonic(), line))


def _pty_emulator() -> tuple[DeviceEmulator, PtyEmulatorServer, list[float]]:
    emulator = DeviceEmulator(load_source("sim", seed=0, events=40), speed=1.0, faults=FaultPlan(disconnect_after=150))
    try:
        server = PtyEmulatorServer(emulator).start()
    except EmulatorServerError as exc:
        pytest.skip(f"no pseudo-terminal here: {exc}")
    returns: list[float] = []  # monotonic times the controller came back from a power cycle

    def watch() -> None:
        was = False
        while server.error is None and not server._stop.is_set():
            now = emulator.booting
            if was and not now:
                returns.append(time.monotonic())
            was = now
            time.sleep(0.01)

    threading.Thread(target=watch, daemon=True).start()
    return emulator, server, returns


def _env(tmp_path: Path) -> dict:
    (tmp_path / "run").mkdir(exist_ok=True)
    return dict(os.environ, PYTHONPATH=str(ROOT), XDG_RUNTIME_DIR=str(tmp_path / "run"))


def test_the_daemon_resumes_events_after_a_controller_power_cycle(tmp_path):
    emulator, server, returns = _pty_emulator()
    models = tmp_path / "models"
    models.mkdir()
    write_model(models, "m.onnx", tiny_model_bytes(), mtime=time.time() - 10)
    trigger = "".join(f"{k} = {v}\n" for k, v in TRIGGER.items())
    cfg = tmp_path / "handover.toml"
    cfg.write_text(f'[device]\nurl = "{server.url}"\n[model]\nfolder = "{models}"\n[trigger]\n{trigger}'
                   "[sinks]\nstdout = true\n")
    log = tmp_path / "run.err"
    err_file = log.open("w")
    proc = subprocess.Popen([sys.executable, "-m", "runtime.cli", "run", "--config", str(cfg)], stdout=subprocess.PIPE,
                            stderr=err_file, text=True, env=_env(tmp_path), cwd=ROOT)
    lines = Lines(proc)
    try:
        deadline = time.monotonic() + 90
        while not returns and time.monotonic() < deadline:
            time.sleep(0.1)
        assert returns, "the emulator did not power-cycle"
        back = returns[0]
        before = [t for t, line in lines.got if '"decision"' in line and t < back]
        while time.monotonic() < back + RECOVER_S + 10:
            if any('"decision"' in line and t > back for t, line in lines.got):
                break
            time.sleep(0.1)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=20)
        err_file.close()
        server.stop()
    err = log.read_text()
    after = [t - back for t, line in lines.got if '"decision"' in line and t > back]
    assert before, "no event before the power cycle"
    print(f"\nfirst event {after[0] if after else None} s after the controller came back")
    assert after and after[0] <= RECOVER_S, f"first event {after[:1]} s after the controller's return; log:\n{err[-2000:]}"
    assert emulator.stats.power_cycles >= 1


def test_dump_reads_on_across_a_controller_power_cycle(tmp_path):
    _, server, returns = _pty_emulator()
    log = tmp_path / "dump.err"
    with log.open("w") as err_file:
        proc = subprocess.Popen([sys.executable, "-m", "runtime.cli", "dump", server.url, "--seconds", "30", "--json"],
                                stdout=subprocess.PIPE, stderr=err_file, text=True, env=_env(tmp_path), cwd=ROOT)
        lines = Lines(proc)
        try:
            proc.wait(timeout=90)
        finally:
            if proc.poll() is None:
                proc.kill()
            server.stop()
    time.sleep(0.2)
    err = log.read_text()
    assert returns, "the emulator did not power-cycle"
    frames = [(t, json.loads(line)) for t, line in lines.got if line.startswith('{"type": "frame"')]
    back = returns[0]
    after = [t - back for t, f in frames if t > back]
    assert len([f for t, f in frames if t < back]) >= 100
    print(f"\nfirst frame {after[0] if after else None} s after the controller came back")
    assert after and after[0] <= RECOVER_S, f"first frame {after[:1]} s after the controller's return; {err[-1500:]}"


def test_dump_frames_survives_a_power_cycle_with_its_default_timeout(tmp_path):
    """Push used to resume 10 s after the power cycle (a retry landing just before the boot ended), and
    ``dump --frames 300`` with its default ``--timeout 10`` gave up."""
    _, server, returns = _pty_emulator()
    try:
        done = subprocess.run([sys.executable, "-m", "runtime.cli", "dump", server.url, "--frames", "300", "--json"],
                              capture_output=True, text=True, env=_env(tmp_path), cwd=ROOT, timeout=90)
    finally:
        server.stop()
    assert returns, "the emulator did not power-cycle"
    frames = [line for line in done.stdout.splitlines() if line.startswith('{"type": "frame"')]
    assert done.returncode == 0 and len(frames) == 300, done.stderr[-1500:]
