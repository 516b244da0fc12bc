"""Helpers of the ROS 2 sink's tests: a daemon over sim:// with a UDP sink beside ROS 2 (no rclpy here)."""

from __future__ import annotations

import socket
import threading
import time
from pathlib import Path

from runtime.config import config_from_dict
from runtime.daemon import Daemon
from tests.tiny_models import tiny_model_bytes, write_model
from tests.waiting import wait_for

TRIGGER = {"fraction": 0.02, "hysteresis": 0.01, "refractory_s": 1.0}
"""The simulated hand presses lightly (synthetic): a low threshold makes every scripted event trigger."""


def ros_sink(daemon: Daemon):
    sinks = [s for s in daemon.sinks.sinks if s.name.startswith("ros2:")]
    return sinks[0] if sinks else None


def daemon_config(tmp_path: Path, url: str, ros2: dict, udp_port: int | None = None):
    models = tmp_path / "models"
    models.mkdir(parents=True, exist_ok=True)
    write_model(models, "m.onnx", tiny_model_bytes(), mtime=time.time() - 10)
    sinks = {"stdout": False, "ros2": True, "udp": [f"127.0.0.1:{udp_port}"] if udp_port else []}
    return config_from_dict({
        "device": {"url": url, "reconnect_min_s": 0.05, "reconnect_max_s": 0.2},
        "model": {"folder": str(models), "poll_interval_s": 0.05}, "trigger": TRIGGER,
        "sinks": sinks, "ros2": ros2})


def udp_socket() -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.setblocking(False)
    return sock


def drain(sock: socket.socket) -> list[str]:
    lines = []
    while True:
        try:
            lines.append(sock.recv(65536).decode())
        except BlockingIOError:
            return lines


def run_until(daemon: Daemon, condition, timeout: float = 15.0) -> None:
    def watch():
        wait_for(lambda: condition(daemon), timeout)
        daemon.request_stop()

    threading.Thread(target=watch, daemon=True).start()
    daemon.run()
