"""The example listeners (examples/listeners/) receive the daemon's real events.

The C listener is compiled with the system's gcc and run; the Python UDP listener and the
rclpy listener run as their own processes. The daemon reads the simulated hand (sim://,
synthetic) with a toy model and sends to all of them at once; each must print the same
description of the same lines a plain UDP socket in the test received.
"""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from runtime.daemon import Daemon
from tests.ros2_helpers import daemon_config, drain, ros_sink, run_until, udp_socket, wait_for
from tests.tiny_models import tiny_model_bytes, write_model

pytest.importorskip("onnx")
ROOT = Path(__file__).resolve().parents[1]
LISTENERS = ROOT / "examples" / "listeners"
N_LINES = 4  # the model announcement and three decisions


def _describe():
    spec = importlib.util.spec_from_file_location("udp_listener", LISTENERS / "udp_listener.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.describe


def _start(cmd: list[str]) -> tuple[subprocess.Popen, int]:
    """Start a listener; returns it and the UDP port it printed (0 for ROS 2)."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = proc.stdout.readline()
    assert first.startswith("listening on"), first + proc.stderr.read()
    return proc, int(first.rsplit(":", 1)[1]) if "udp" in first else 0


def _printed(proc: subprocess.Popen) -> list[str]:
    try:
        out, err = proc.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
    assert proc.returncode == 0, err
    return out.splitlines()


def _send_real_events(tmp_path: Path, ports: list[int], ros2: bool) -> list[str]:
    """Run the daemon until it sent N_LINES lines to every port (and ROS 2), besides the shadow lines of a
    candidate in ``[model] shadow`` (the listeners must skip them); the test socket's copy of the lines the
    listeners print, after checking that shadow lines were among them."""
    mine = udp_socket()
    cfg = daemon_config(tmp_path, "sim://?seed=0&events=4&realtime=0&loop=0", {}, mine.getsockname()[1])
    targets = (*cfg.sinks.udp, *(f"127.0.0.1:{p}" for p in ports))
    shadow = tmp_path / "shadow"
    shadow.mkdir()
    write_model(shadow, "candidate.onnx", tiny_model_bytes(bias=(0.0, 1.0, 0.0, 0.0)))
    cfg = replace(cfg, sinks=replace(cfg.sinks, udp=targets, ros2=ros2), model=replace(cfg.model, shadow=str(shadow)))
    daemon = Daemon(cfg, on_event=lambda _e: wait_for(lambda: daemon.shadow.candidate is not None))
    if ros2:
        sink = ros_sink(daemon)
        assert sink is not None and wait_for(lambda: sink._events.get_subscription_count() >= 1), "rclpy listener not matched"
    run_until(daemon, lambda d: d.health.events >= N_LINES - 1 and (c := d.shadow.comparison) is not None
              and c.compared >= N_LINES - 1)
    lines = drain(mine)
    mine.close()
    assert "shadow" in {json.loads(line)["type"] for line in lines}
    return [line for line in lines if json.loads(line)["type"] != "shadow"]


def test_c_and_python_udp_listeners_print_the_real_events(tmp_path):
    gcc = shutil.which("gcc")
    if gcc is None:
        pytest.skip("gcc is not installed: the C listener cannot be built (apt-get install gcc)")
    binary = tmp_path / "udp_listener"
    subprocess.run([gcc, "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-o", str(binary),
                    str(LISTENERS / "udp_listener.c")], check=True, capture_output=True, text=True)
    c_proc, c_port = _start([str(binary), "0", str(N_LINES)])
    py_proc, py_port = _start([sys.executable, str(LISTENERS / "udp_listener.py"), "0", str(N_LINES)])
    lines = _send_real_events(tmp_path, [c_port, py_port], ros2=False)
    describe = _describe()
    expected = [describe(json.loads(line)) for line in lines[:N_LINES]]
    assert _printed(c_proc) == expected
    assert _printed(py_proc) == expected
    first, second = (json.loads(x) for x in lines[:2])
    assert expected[0] == f"model {first['model_id']} version=1 previous=null"
    assert expected[1].startswith(f"decision {second['class']} latency_us={second['latency_us']} ")


def test_rclpy_listener_prints_the_real_events(tmp_path, monkeypatch):
    pytest.importorskip("rclpy", reason="rclpy is not installed: the ros extra (./dev test installs it)")
    monkeypatch.setenv("ROS_DOMAIN_ID", str(1 + (os.getpid() + 50) % 100))  # this run's own domain
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    monkeypatch.delenv("RMW_IMPLEMENTATION", raising=False)
    proc, _ = _start([sys.executable, str(LISTENERS / "ros2_listener.py"), "/handover", str(N_LINES)])
    lines = _send_real_events(tmp_path, [], ros2=True)
    describe = _describe()
    assert _printed(proc) == [describe(json.loads(line)) for line in lines[:N_LINES]]
