"""The daemon, started as systemd starts it and streaming, never loads the training stack.

`test_cli.py` guards the dispatcher's import; this starts `handover run` in its own process,
lets it classify frames from the simulated hand, stops it with SIGTERM and then lists what the
process imported: a heavy import anywhere on the daemon's path (runtime.daemon, sinks, model,
transports) shows up here.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tests.tiny_models import tiny_model_bytes, write_model

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("sklearn", "scipy", "matplotlib", "onnx", "trainer", "tqdm", "joblib", "rosbags",
         "rclpy", "std_msgs", "sensor_msgs", "diagnostic_msgs", "runtime.ros2", "runtime.ros2_node")

_DRIVER = """
import os, signal, sys, threading, time
from runtime.cli import main
threading.Timer(float(sys.argv[2]), lambda: os.kill(os.getpid(), signal.SIGTERM)).start()
rc = main(["run", "--config", sys.argv[1]])
heavy = sorted(({m.split(".")[0] for m in sys.modules} | set(sys.modules)) & set(sys.argv[3].split(",")))
print("HEAVY", ",".join(heavy), file=sys.stderr)
sys.exit(rc)
"""


def test_streaming_daemon_never_imports_training_packages(tmp_path):
    models = tmp_path / "models"
    models.mkdir()
    write_model(models, "m.onnx", tiny_model_bytes())
    status = tmp_path / "status.json"
    cfg = tmp_path / "h.toml"
    cfg.write_text(
        f'health_file = "{status}"\n'
        '[device]\nurl = "sim://?seed=1&events=3&realtime=0"\n'
        f'[model]\nfolder = "{models}"\n'
        '[scene]\npads = "distal"\n'
    )
    import os

    home = tmp_path / "home"  # onnxruntime's telemetry would keep its store here
    env = {k: v for k, v in os.environ.items() if k != "ORT_DISABLE_TELEMETRY"}
    proc = subprocess.run(
        [sys.executable, "-c", _DRIVER, str(cfg), "4", ",".join(HEAVY)],
        cwd=ROOT, capture_output=True, text=True, timeout=60, env={**env, "HOME": str(home)},
    )
    assert proc.returncode == 0, proc.stderr
    assert not (home / ".cache" / "Microsoft").exists()  # no device id, no telemetry store (runtime/__init__.py)
    heavy_line = [line for line in proc.stderr.splitlines() if line.startswith("HEAVY")]
    assert heavy_line == ["HEAVY "], proc.stderr
    health = json.loads(status.read_text())
    assert health["frames_received"] > 0 and health["decisions"] > 0, health  # it really streamed and classified, not just started
    assert proc.stdout.strip(), "the tiny model reports events on stdout"


def test_the_daemon_install_is_numpy_onnxruntime_pyserial_only():
    """ROS 2, training and benchmarks live in extras; the robot PC's install stays these three."""
    import tomllib

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    names = sorted(d.split(">")[0].split("=")[0].split("[")[0].strip() for d in project["dependencies"])
    assert names == ["numpy", "onnxruntime", "pyserial"]
    extras = project["optional-dependencies"]
    assert extras["ros"] and all(d.startswith("ros-") for d in extras["ros"])
    assert not [d for name, deps in extras.items() if name != "ros" for d in deps if d.startswith("ros-")]
