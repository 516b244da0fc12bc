"""``handover run --check`` says what it checked and what not; with ``--device`` it opens the device
for a few seconds and reports frames and rate (the real emulator on loopback TCP), or one line
saying why nothing came (nothing listening), exit 1."""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
from pathlib import Path

from firmware_io.emulator.device import DeviceEmulator
from firmware_io.emulator.frame_source import load_source
from firmware_io.emulator.server import TcpEmulatorServer
from runtime.device_check import PROBE_S
from tests.tiny_models import tiny_model_bytes, write_model

ROOT = Path(__file__).resolve().parents[1]


def _check(tmp_path: Path, url: str, *more: str) -> subprocess.CompletedProcess:
    models = tmp_path / "models"
    models.mkdir(exist_ok=True)
    write_model(models, "m.onnx", tiny_model_bytes())
    cfg = tmp_path / "h.toml"
    cfg.write_text(f'[device]\nurl = "{url}"\n[model]\nfolder = "{models}"\n')
    (tmp_path / "run").mkdir(exist_ok=True)
    env = dict(os.environ, PYTHONPATH=str(ROOT), XDG_RUNTIME_DIR=str(tmp_path / "run"))
    return subprocess.run([sys.executable, "-m", "runtime.cli", "run", "--config", str(cfg), "--check", *more],
                          capture_output=True, text=True, cwd=ROOT, env=env, timeout=120)


def test_check_says_it_did_not_open_the_device(tmp_path):
    proc = _check(tmp_path, "tcp://127.0.0.1:9")
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    assert "would serve model" in out
    assert re.search(r"^checked: .*model.*scene\.pads", out, re.M)
    assert re.search(r"^not checked: the device itself \(add --device", out, re.M)


def test_check_device_reports_frames_and_rate_of_the_emulator(tmp_path):
    server = TcpEmulatorServer(DeviceEmulator(load_source("sim", seed=0, events=4), speed=1.0)).start()
    try:
        proc = _check(tmp_path, server.url, "--device")
    finally:
        server.stop()
    assert proc.returncode == 0, proc.stderr
    line = next(x for x in proc.stdout.splitlines() if x.startswith(f"device {server.url}:") and " frames in " in x)
    m = re.search(r"(\d+) frames in ([\d.]+) s \(([\d.]+) frames/s; ([\d.]+) Hz on the device's clock\); 6 pads, "
                  r"486 taxels, firmware 2\.9\.0\.0", line)
    assert m, line
    frames, rate, device_hz = int(m.group(1)), float(m.group(3)), float(m.group(4))
    assert frames >= 30 and 20 <= rate <= 40 and abs(device_hz - 32) < 2, line
    assert "not checked: the device itself" not in proc.stdout and "not checked: whether the UDP" in proc.stdout
    assert proc.stdout.strip().splitlines()[-1] == line, "the device's verdict is the last line, after the lists"


def test_check_device_with_nothing_listening_is_one_line_and_exit_1(tmp_path):
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    proc = _check(tmp_path, f"tcp://127.0.0.1:{port}", "--device")
    assert proc.returncode == 1, proc.stdout + proc.stderr
    lines = [line for line in proc.stderr.strip().splitlines() if "warning: stream setting" not in line]
    assert len(lines) == 1 and lines[0].startswith(f"handover run: device tcp://127.0.0.1:{port}: cannot read it"), lines
    assert "Traceback" not in proc.stderr


def test_the_device_check_waits_for_a_tcp_connection_at_most_its_bound(monkeypatch):
    """With connect_timeout=3600 a host that never answered held 'run --check --device' ("for 3 s") until
    the kernel gave up (2 minutes), and the line said 3600 s; a shorter timeout in the URL is kept."""
    from firmware_io.transports import tcp
    from runtime.device_check import PROBE_CONNECT_S, probe_device

    asked: list[float] = []

    def silent_host(address, timeout):
        asked.append(timeout)
        raise TimeoutError

    monkeypatch.setattr(tcp.socket, "create_connection", silent_host)
    probe = probe_device("tcp://192.0.2.7:13000?connect_timeout=3600")
    assert asked == [PROBE_CONNECT_S] and probe.problem.endswith(f"no answer within {PROBE_CONNECT_S:g} s (hand powered? cable?)")
    probe_device("tcp://192.0.2.7:13000?connect_timeout=0.5")
    probe_device("tcp://192.0.2.7:13000")
    assert asked[1:] == [0.5, PROBE_CONNECT_S]
    assert probe_device("tcp://192.0.2.7:99999").problem.startswith("cannot read it: ")


def test_check_device_says_what_it_waits_for_while_the_controller_boots(tmp_path):
    """A check right after another host left (the controller resets and is deaf while it boots, 8 s on
    the robot) sat silent after "opening ..."; it says it waits, for what and how long at most."""
    emulator = DeviceEmulator(load_source("sim", seed=0, events=4), speed=1.0, boot_s=1.5, boot_query_s=1.2)
    emulator.power_cycle()
    server = TcpEmulatorServer(emulator).start()
    try:
        proc = _check(tmp_path, server.url, "--device")
    finally:
        server.stop()
    assert proc.returncode == 0, proc.stderr
    lines = [x for x in proc.stdout.splitlines() if x.startswith(("opening", "device"))]
    assert lines[0].startswith("opening") and len(lines) == 4, lines
    assert re.fullmatch(rf"device {re.escape(server.url)}: no answer yet; waiting up to \d+ s for the controller "
                        r"to answer \(.*about 8 s\) \.\.\.", lines[1]), lines
    assert lines[2] == f"device {server.url}: reading frames for up to {PROBE_S:g} s ...", lines
    assert " frames in " in lines[3], lines


def test_the_check_says_it_reads_frames_and_for_how_long_once_the_controller_answered():
    """After the controller answered, the check read frames for PROBE_S with nothing on screen (4-6 s on a slow
    machine): a user thought it hung. One line says what it does and for how long at most, before the read."""
    from firmware_io.layout import SensorLayout
    from runtime.device_check import PROBE_S, probe_device

    said: list[str] = []

    class Answering:
        controller = sensor = None

        def open(self):
            said.append("open")
            return SensorLayout.sdh2()

        def start(self) -> None:
            pass

        def read_frame(self, timeout):
            said.append("read")
            raise OSError("the cable came out")

        def close(self, stop_timeout) -> None:
            pass

    probe_device("tcp://10.0.0.9", client_factory=lambda url: Answering(), on_wait=said.append)
    assert said == ["open", f"tcp://10.0.0.9: reading frames for up to {PROBE_S:g} s ...", "read"], said


def test_dump_and_the_check_write_a_serial_number_alike(capsys):
    """``dump`` wrote the controller's serial in decimal (12345), ``run --check --device`` the sensor's in hex
    (00003039): the same number twice, unrecognisable. Both go through ``replies.serial_text`` now."""
    from firmware_io.emulator.identity import DEFAULT_SERIAL
    from firmware_io.wire.replies import serial_text
    from runtime.cli import main
    from runtime.device_check import probe_device

    assert serial_text(DEFAULT_SERIAL) == "00003039" and serial_text(0x1D9B0057) == "1D9B0057"  # a .dsa <serial_nr>
    assert probe_device("sim://?realtime=0", seconds=0.2).line().endswith(f", sensor serial {serial_text(DEFAULT_SERIAL)}")
    assert main(["dump", "sim://?realtime=0", "--frames", "1", "--all-frames"]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert first == f"sim://?realtime=0: controller firmware 2.9.0.0, serial {serial_text(DEFAULT_SERIAL)}", first
