"""``./dev bench ros2``: the ROS 2 sink. Event latency from the decision to an rclpy subscriber in
another process (median, p99, p99.9), and pad images delivered per second with none lost.

The daemon reads the simulated hand (sim://, synthetic, sped up so that a minute holds enough
events) with the product's default model, trained on the simulated protocol (quick; ROS delivery
does not depend on what the model computes), publishes events and all six pads; a subscriber process records when each line
arrives and counts the images. Latency = subscriber's wall clock at the callback minus the
event's ``time`` (stamped right after the decision, before any sink), same machine and clock.
Needs the ros and train extras and a sourced ROS 2 (options: ``./dev bench --help``).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from firmware_io.frame_timing import NOMINAL_RATE_HZ
from trainer.measure import command_line, load_average, machine_info, train_default_model, write_results

ROOT = Path(__file__).resolve().parents[1]
PADS = ("finger_0_proximal", "finger_0_distal", "thumb_proximal", "thumb_distal", "finger_2_proximal", "finger_2_distal")
SECONDS, QUICK_SECONDS, SPEED = 60.0, 5.0, 16.0
PAD_RATE_HZ = NOMINAL_RATE_HZ
"""Default ``--pad-rate``: an image of every frame, the most the ROS 2 sink can be asked for."""


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
        node.create_subscription(Image, f"{namespace}/pads/{pad}", count, 1000)
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


def measure(seconds: float, speed: float, pad_rate: float) -> dict:
    from runtime.config import config_from_dict
    from runtime.daemon import Daemon

    os.environ.setdefault("ROS_DOMAIN_ID", str(1 + os.getpid() % 100))
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    child = subprocess.Popen([sys.executable, "-m", "benchmarks.ros2", "--subscriber"], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, text=True, cwd=ROOT)
    ready, udp_port = [*child.stdout.readline().split(), "", ""][:2]
    if ready != "ready":
        child.kill()
        raise RuntimeError("the ROS 2 subscriber process did not start (is rclpy importable? source ROS 2 first)")
    work = Path(tempfile.mkdtemp())
    models = work / "models"
    models.mkdir()
    served = models / "bench.onnx"
    shutil.copyfile(train_default_model(work, quick=True), served)  # the product default (synthetic data)
    settled = time.time() - 10  # an old file: the watcher serves it at once (no copy in progress)
    os.utime(served, (settled, settled))
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


def latency_figures(us: np.ndarray) -> dict | None:
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
        "event_latency_us": latency_figures(lat),
        "udp_event_latency_us": latency_figures(udp_lat),
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


def run(args) -> dict:
    seconds = args.seconds or (QUICK_SECONDS if args.quick else SECONDS)
    speed, pad_rate = args.speed or SPEED, args.pad_rate or PAD_RATE_HZ
    load_before, date = load_average(), time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    args.say(f"ros2: {seconds:g} s of the simulated hand at {speed:g}x, events and pad images to a subscriber ...")
    result = measure(seconds, speed, pad_rate)
    result.update(machine=machine_info(), load_before=load_before, load_after=load_average(),
                  command=command_line("ros2", args), date=date)
    result["ros2_event_p99_us"] = result["event_latency_us"]["p99"] if result["event_latency_us"] else None
    write_results(args.out, "ros2", result, markdown(result))
    return result


def markdown(result: dict) -> list[str]:
    s, lat, udp = result["settings"], result["event_latency_us"], result["udp_event_latency_us"]
    hot = result["decision_latency_us_hot_path"]
    return f"""# ROS 2 sink benchmark

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
Run on {result['date']}.""".splitlines()


if __name__ == "__main__":  # the subscriber process (python -m benchmarks.ros2 --subscriber)
    if sys.argv[1:] == ["--subscriber"]:
        subscriber("/handover")
