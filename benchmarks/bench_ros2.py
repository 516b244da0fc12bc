"""Benchmark: the ROS 2 sink. Event latency from the decision to an rclpy subscriber in another
process (median, p99, p99.9), and pad images delivered per second with none lost.

The daemon reads the simulated hand (sim://, synthetic, sped up so that a minute holds enough
events) with a toy model from tests/tiny_models.py (ROS delivery does not depend on what the
model computes), publishes events and all six pads; a subscriber process records when each line
arrives and counts the images. Latency = subscriber's wall clock at the callback minus the
event's ``time`` (stamped right after the decision, before any sink), same machine and clock.

Usage: ``.venv/bin/python benchmarks/bench_ros2.py [--seconds 60] [--speed 16] [--pad-rate 32]``
(needs the ros and train extras). Writes results/ros2.json and results/ros2.md.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

PADS = ("finger_0_proximal", "finger_0_distal", "thumb_proximal", "thumb_distal", "finger_2_proximal", "finger_2_distal")


def subscriber(namespace: str) -> None:
    """Child process: record events (ROS 2 and, for comparison, UDP) and pad images until stdin
    closes, then print JSON."""
    import socket

    import rclpy
    from sensor_msgs.msg import Image
    from std_msgs.msg import String

    rclpy.init()
    node = rclpy.create_node("bench_subscriber")
    events: list[tuple[float, str]] = []
    images = dict.fromkeys(PADS, 0)
    node.create_subscription(String, f"{namespace}/events", lambda m: events.append((time.time(), m.data)), 1000)
    for pad in PADS:
        def count(_msg: Image, pad: str = pad) -> None:
            images[pad] += 1
        node.create_subscription(Image, f"{namespace}/pads/{pad}", count, 100)
    done = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.read(), done.set()), daemon=True).start()
    udp_events: list[tuple[float, str]] = []
    udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    udp.bind(("127.0.0.1", 0))
    udp.settimeout(0.05)

    def listen_udp() -> None:
        while not done.is_set():
            try:
                data = udp.recv(65536)
            except TimeoutError:
                continue
            udp_events.append((time.time(), data.decode()))

    threading.Thread(target=listen_udp, daemon=True).start()
    print("ready", udp.getsockname()[1], flush=True)
    while not done.is_set():
        rclpy.spin_once(node, timeout_sec=0.05)
    end = time.monotonic() + 1.0  # what is still in flight
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    print(json.dumps({"events": events, "udp_events": udp_events, "images": images}), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()


def run(seconds: float, speed: float, pad_rate: float) -> dict:
    from runtime.config import config_from_dict
    from runtime.daemon import Daemon
    from tests.tiny_models import tiny_model_bytes, write_model

    os.environ.setdefault("ROS_DOMAIN_ID", str(1 + os.getpid() % 100))
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    child = subprocess.Popen([sys.executable, __file__, "--subscriber"], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, text=True)
    ready, udp_port = child.stdout.readline().split()
    assert ready == "ready"
    models = Path(tempfile.mkdtemp()) / "models"
    models.mkdir()
    write_model(models, "toy.onnx", tiny_model_bytes(), mtime=time.time() - 10)
    url = f"sim://?seed=0&events=40&realtime=1&speed={speed:g}&loop=1"
    cfg = config_from_dict({
        "device": {"url": url}, "model": {"folder": str(models)},
        "trigger": {"fraction": 0.02, "hysteresis": 0.01, "refractory_s": 1.0},
        "sinks": {"stdout": False, "ros2": True, "udp": [f"127.0.0.1:{udp_port}"]}, "ros2": {"pads": True, "pad_rate_hz": pad_rate, "depth": 1000},
        "log_level": "warning"})
    daemon = Daemon(cfg)
    sink = next(s for s in daemon.sinks.sinks if s.name.startswith("ros2:"))
    deadline = time.monotonic() + 20
    while sink._events.get_subscription_count() < 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    runner = threading.Thread(target=daemon.run)
    runner.start()
    while daemon.health.device_state != "streaming" and runner.is_alive():
        time.sleep(0.01)  # the simulated session is generated first; the window starts with the stream
    started = time.monotonic()
    time.sleep(seconds)
    daemon.request_stop()
    runner.join()
    wall = time.monotonic() - started
    child.stdin.close()
    got = json.loads(child.stdout.readline())
    child.wait(timeout=10)
    return summarise(got, daemon, sink, wall, dict(seconds=seconds, speed=speed, pad_rate_hz=pad_rate, url=url))


def percentiles(us: np.ndarray) -> dict | None:
    if not us.size:
        return None
    p50, p99, p999 = np.percentile(us, [50, 99, 99.9])
    return {"n": int(us.size), "median": round(float(p50), 1), "p99": round(float(p99), 1),
            "p99_9": round(float(p999), 1), "max": round(float(us.max()), 1)}


def summarise(got: dict, daemon, sink, wall: float, settings: dict) -> dict:
    received = [(t, json.loads(line)) for t, line in got["events"]]
    decisions = [(t, e) for t, e in received if e["type"] == "decision"]
    lat = np.array([(t - e["time"]) * 1e6 for t, e in decisions])
    udp = [(t, json.loads(line)) for t, line in got["udp_events"]]
    udp_lat = np.array([(t - e["time"]) * 1e6 for t, e in udp if e["type"] == "decision"])
    hot = daemon.health.snapshot()
    images = sum(got["images"].values())
    return {
        "settings": settings,
        "wall_s": round(wall, 2),
        "events_sent": daemon.health.events,
        "events_received": len(decisions),
        "lines_sent": sink.sent,
        "lines_received": len(received),
        "event_latency_us": percentiles(lat),
        "udp_event_latency_us": percentiles(udp_lat),
        "same_lines_on_udp": [line for _, line in got["udp_events"]] == [line for _, line in got["events"]],
        "pad_images_published": sink.pad_images,
        "pad_images_received": images,
        "pad_images_lost": sink.pad_images - images,
        "pad_images_per_s": round(images / wall, 1),
        "pad_images_per_topic": got["images"],
        "frames": hot["frames_received"],
        "decision_latency_us_hot_path": {"p50": hot["latency_p50_us"], "p99": hot["latency_p99_us"],
                                         "max": hot["latency_max_us"]},
        "missed_deadlines": hot["missed_deadlines"],
        "sink_errors": daemon.sinks.errors,
    }


def write(result: dict) -> None:
    out = ROOT / "results"
    (out / "ros2.json").write_text(json.dumps(result, indent=1) + "\n")
    s, lat, udp, m = result["settings"], result["event_latency_us"], result["udp_event_latency_us"], result["machine"]
    hot = result["decision_latency_us_hot_path"]
    md = f"""# ROS 2 sink benchmark

Synthetic stream: the simulated hand (`{s['url']}`, {s['speed']:g}x real time, {result['frames']} frames in
{result['wall_s']} s) with a toy model; the daemon publishes events on `/handover/events` and all six pads
(mono16) at up to {s['pad_rate_hz']:g} images/s each; an rclpy subscriber in another process receives them
(Fast DDS, reliable QoS, discovery on localhost). The same process also receives the events over
UDP, for a comparison under the same load.

| figure | value |
|---|---|
| events: sent / received | {result['events_sent']} / {result['events_received']} (all lines: {result['lines_sent']} / {result['lines_received']}) |
| event latency, decision -> subscriber: median | {lat['median']:.0f} us |
| p99 / p99.9 / max | {lat['p99']:.0f} / {lat['p99_9']:.0f} / {lat['max']:.0f} us (n = {lat['n']}) |
| the same events over UDP to the same process: median / p99 / max | {udp['median']:.0f} / {udp['p99']:.0f} / {udp['max']:.0f} us (same lines: {result['same_lines_on_udp']}) |
| pad images: published / received / lost | {result['pad_images_published']} / {result['pad_images_received']} / {result['pad_images_lost']} |
| pad images delivered per second | {result['pad_images_per_s']} (6 pads) |
| decision latency in the daemon (frame arrival -> decision) p50 / p99 / max | {hot['p50']} / {hot['p99']} / {hot['max']} us |
| missed deadlines, sink errors | {result['missed_deadlines']}, {result['sink_errors']} |

With n = {lat['n']} events the p99.9 is the largest few values, not a stable tail figure.
Machine: {m['cpu']}, {m['cores_visible']} cores visible, **shared with other helpers' jobs while this ran**
(load average {m['load_avg_1m']:.2f} before the run), Python {m['python']}, {m['platform']}.
Command: `{result['command']}` ({result['date']}).
"""
    (out / "ros2.md").write_text(md)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--speed", type=float, default=16.0, help="sim:// speed-up (more events per minute)")
    ap.add_argument("--pad-rate", type=float, default=32.0, help="[ros2] pad_rate_hz")
    ap.add_argument("--subscriber", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--no-write", action="store_true", help="print only")
    args = ap.parse_args(argv)
    if args.subscriber:
        subscriber("/handover")
        return 0
    from benchmarks.bench_decode import machine

    before, date = machine(), time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    result = run(args.seconds, args.speed, args.pad_rate)
    result.update(machine=before, command=" ".join(["python", *sys.argv]), date=date)
    print(json.dumps({k: v for k, v in result.items() if k != "pad_images_per_topic"}))
    if not args.no_write:
        write(result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
