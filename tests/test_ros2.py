"""The ROS 2 sink with a real rclpy node: the daemon reads the simulated hand (sim://) and a
subscriber node in this test receives its events, model announcements, diagnostics and pad
images, and checks them against what the UDP sink sent. A ROS failure is one line and the
other sinks keep delivering.

Each test process uses its own ROS_DOMAIN_ID and keeps discovery on this machine
(ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST), so parallel runs never hear each other.
The models are toy graphs (tests/tiny_models.py) and the data is synthetic.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from runtime.config import Ros2Config
from runtime.daemon import Daemon
from runtime.sinks import ModelAnnouncement
from tests.ros2_helpers import daemon_config, drain, ros_sink, run_until, udp_socket, wait_for
from tests.waiting import sigterm_seconds

pytest.importorskip("onnx")
rclpy = pytest.importorskip("rclpy", reason="rclpy is not installed: the ros extra (./dev test installs it)")
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from rclpy.signals import SignalHandlerOptions  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402
from std_msgs.msg import String  # noqa: E402

pytestmark = pytest.mark.ros2
ROOT = Path(__file__).resolve().parents[1]
SCHEMA = json.loads((ROOT / "docs" / "events.schema.json").read_text())
PAD_TOPICS = ("finger_0_proximal", "finger_0_distal", "thumb_proximal", "thumb_distal",
              "finger_2_proximal", "finger_2_distal")


@pytest.fixture(autouse=True, scope="module")
def ros_isolation():
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("ROS_DOMAIN_ID", str(1 + os.getpid() % 100))
        mp.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        mp.delenv("RMW_IMPLEMENTATION", raising=False)
        yield


class Listener:
    """A separate rclpy node (own context) that records what the daemon publishes."""

    def __init__(self, ns: str = "/handover") -> None:
        self.context = Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("test_listener", context=self.context)
        self.events: list[str] = []
        self.models: list[str] = []
        self.diagnostics: list[DiagnosticArray] = []
        self.images: dict[str, list[Image]] = {t: [] for t in PAD_TOPICS}
        n = self.node
        n.create_subscription(String, f"{ns}/events", lambda m: self.events.append(m.data), 1000)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        n.create_subscription(String, f"{ns}/model", lambda m: self.models.append(m.data), latched)
        n.create_subscription(DiagnosticArray, "/diagnostics", self.diagnostics.append, 100)
        for topic in PAD_TOPICS:
            n.create_subscription(Image, f"{ns}/pads/{topic}", self.images[topic].append, 100)
        self.grasp = n.create_publisher(String, f"{ns}/grasp", 10)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(n)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        with contextlib.suppress(Exception):  # shut down from the test
            self.executor.spin()

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=1.0)
        self.context.try_shutdown()
        self.thread.join(timeout=2.0)


def _state(diagnostics: DiagnosticArray) -> str:
    return next(kv.value for kv in diagnostics.status[0].values if kv.key == "device_state")


def test_events_diagnostics_and_pads_reach_an_rclpy_subscriber(tmp_path):
    jsonschema = pytest.importorskip("jsonschema")
    from firmware_io.emulator.frame_source import load_source

    udp = udp_socket()
    url = "sim://?seed=0&events=4&realtime=1&speed=8"
    cfg = daemon_config(tmp_path, url, {"pads": True, "pad_rate_hz": 50.0}, udp.getsockname()[1])
    listener = Listener()
    daemon = Daemon(cfg)
    ros = ros_sink(daemon)
    try:
        assert ros is not None, "the ROS 2 sink did not start"
        assert wait_for(lambda: ros._events.get_subscription_count() >= 1), "the test's subscriber was never matched"
        run_until(daemon, lambda d: d.health.events >= 3 and any(_state(x) == "streaming" for x in listener.diagnostics)
                   and all(len(v) >= 2 for v in listener.images.values()))
        udp_lines = drain(udp)
        assert wait_for(lambda: len(listener.events) >= len(udp_lines), 5.0)
        assert wait_for(lambda: _state(listener.diagnostics[-1]) == "stopped", 5.0), "no last health at shutdown"
    finally:
        listener.close()
        udp.close()
    # events: exactly the UDP lines, in order, each valid against the documented schema
    assert listener.events == udp_lines and len(udp_lines) >= 4
    for line in udp_lines:
        jsonschema.validate(json.loads(line), SCHEMA)
    decisions = [json.loads(x) for x in udp_lines if json.loads(x)["type"] == "decision"]
    assert len(decisions) == daemon.health.events >= 3
    first = json.loads(udp_lines[0])
    assert first["type"] == "model" and first["model_version"] == 1 and first["previous_model_id"] is None
    assert listener.models and listener.models[-1] == udp_lines[0]
    # health on /diagnostics
    streaming = [d for d in listener.diagnostics if _state(d) == "streaming"]
    assert streaming, [_state(d) for d in listener.diagnostics]
    status = streaming[-1].status[0]  # the last one while streaming (shutdown may send more than one after it)
    values = {kv.key: kv.value for kv in status.values}
    assert status.hardware_id == url and "tactile handover" in status.name
    for key in ("device_state", "frame_rate_hz", "crc_errors", "stalls", "reconnects", "model_id", "model_swaps"):
        assert key in values, key
    assert values["model_id"] == first["model_id"] and values["model_swaps"] == "0"
    assert values["device_state"] == "streaming" and status.level == DiagnosticStatus.OK
    # which daemon: the instance name, in the key/value pairs, the message and every event line
    from runtime.instance_name import default_instance

    assert values["instance"] == default_instance(url) and status.message.startswith(f"{values['instance']}: ")
    assert all(json.loads(x)["instance"] == values["instance"] for x in udp_lines)
    assert values["trigger"].split(" ")[0] in ("onset", "threshold", "baseline")
    # pads: mono16, rows x columns as on the pad, the values of a frame the simulated hand sent
    frames = load_source("sim", seed=0, events=4).frames
    layout = daemon.detector.layout
    for index, topic in enumerate(PAD_TOPICS):
        sent = {row.tobytes() for row in frames[:, layout.matrix_slice(index)]}
        for img in listener.images[topic]:
            m = layout.matrices[index]
            assert (img.encoding, img.height, img.width, img.step) == ("mono16", m.cells_y, m.cells_x, 2 * m.cells_x)
            assert img.header.frame_id == topic and bytes(img.data) in sent
    assert (layout.matrices[0].cells_y, layout.matrices[1].cells_y) == (14, 13)
    assert ros.pad_images >= sum(len(v) for v in listener.images.values())


def test_the_grasp_topic_reaches_the_daemon(tmp_path, caplog):
    cfg = daemon_config(tmp_path, "sim://?realtime=0", {"grasp": True, "namespace": "/lab/hand", "trust": "local_users"})
    daemon = Daemon(cfg)
    listener = Listener("/lab/hand")
    try:
        assert wait_for(lambda: listener.grasp.get_subscription_count() >= 1), "grasp subscription never matched"
        listener.grasp.publish(String(data="closed"))
        assert wait_for(lambda: daemon.detector.grasp_request == (True, "ros2"))
        listener.grasp.publish(String(data=" Open\n"))
        assert wait_for(lambda: daemon.detector.grasp_request == (False, "ros2"))
        with caplog.at_level(logging.WARNING, logger="handover.ros2"):
            listener.grasp.publish(String(data="halfway"))
            assert wait_for(lambda: "expected 'closed' or 'open'" in caplog.text, 5.0)
        assert daemon.detector.grasp_request == (False, "ros2")
    finally:
        daemon.sinks.close()
        listener.close()


def test_the_arm_topic_and_joint_states_reach_the_daemon(tmp_path, caplog):
    from sensor_msgs.msg import JointState

    cfg = daemon_config(tmp_path, "sim://?realtime=0", {"arm": True, "namespace": "/lab/hand", "trust": "local_users",
                                                         "joint_states": "/robot/joint_states", "joint_speed": 0.1})
    daemon = Daemon(cfg)
    listener = Listener("/lab/hand")
    arm = listener.node.create_publisher(String, "/lab/hand/arm", 10)
    joints = listener.node.create_publisher(JointState, "/robot/joint_states", 10)
    try:
        assert wait_for(lambda: arm.get_subscription_count() >= 1 and joints.get_subscription_count() >= 1)
        arm.publish(String(data=" Moving\n"))
        assert wait_for(lambda: daemon.detector.arm_request == (True, "ros2"))
        arm.publish(String(data="still"))
        assert wait_for(lambda: daemon.detector.arm_request == (False, "ros2"))
        with caplog.at_level(logging.WARNING, logger="handover.ros2"):
            arm.publish(String(data="flying"))
            assert wait_for(lambda: "expected 'moving' or 'still'" in caplog.text, 5.0)
        assert daemon.detector.arm_request == (False, "ros2")

        def state(t: float, position: list[float], velocity: list[float]) -> JointState:
            msg = JointState(name=["shoulder", "elbow"], position=position, velocity=velocity)
            msg.header.stamp.sec, msg.header.stamp.nanosec = int(t), int((t % 1) * 1e9)
            return msg

        joints.publish(state(100.0, [0.0, 0.0], [0.0, 0.5]))  # the elbow turns at 0.5 rad/s
        assert wait_for(lambda: daemon.detector.arm_request == (True, "ros2"))
        joints.publish(state(100.1, [0.0, 0.05], [0.0, 0.01]))
        assert wait_for(lambda: daemon.detector.arm_request == (False, "ros2"))
        joints.publish(state(101.0, [0.0, 0.05], []))  # positions only: speed from the change
        joints.publish(state(101.1, [0.0, 0.10], []))  # 0.5 rad/s
        assert wait_for(lambda: daemon.detector.arm_request == (True, "ros2"))
    finally:
        daemon.sinks.close()
        listener.close()


def test_the_outcome_topic_reaches_field_capture(tmp_path):
    cfg = daemon_config(tmp_path, "sim://?realtime=0", {"outcome": True, "namespace": "/lab/hand", "trust": "local_users"})
    daemon = Daemon(cfg)
    heard: list[tuple[str, str]] = []
    daemon.robot.capture = SimpleNamespace(outcome=lambda word, source: heard.append((word, source)))
    listener = Listener("/lab/hand")
    outcome = listener.node.create_publisher(String, "/lab/hand/outcome", 10)
    try:
        assert wait_for(lambda: outcome.get_subscription_count() >= 1), "outcome subscription never matched"
        outcome.publish(String(data=" Taken\n"))
        assert wait_for(lambda: heard == [("taken", "ros2")])  # field capture checks the word (tests/test_field_capture.py)
    finally:
        daemon.sinks.close()
        listener.close()


def test_without_sros2_or_a_trust_the_steering_inputs_are_not_subscribed(tmp_path, caplog):
    """LOCALHOST discovery (this module's environment) still trusts every local user: by default grasp, arm
    and joint states are not subscribed (one warning says so), nothing another node sends reaches the
    detector, and the events topic still publishes."""
    with caplog.at_level(logging.WARNING, logger="handover.ros2"):
        daemon = Daemon(daemon_config(tmp_path, "sim://?realtime=0", {"grasp": True, "arm": True,
                                                                     "joint_states": "/robot/joint_states"}))
    listener = Listener()
    arm = listener.node.create_publisher(String, "/handover/arm", 10)
    try:
        ros = ros_sink(daemon)
        assert wait_for(lambda: ros._events.get_subscription_count() >= 1), "the events topic was never matched"
        assert listener.grasp.get_subscription_count() == 0 and arm.get_subscription_count() == 0
        assert ros.node.count_subscribers("/robot/joint_states") == 0
        listener.grasp.publish(String(data="open"))
        arm.publish(String(data="moving"))
        time.sleep(0.3)
        assert daemon.detector.grasp_request is None and daemon.detector.arm_request is None
    finally:
        daemon.sinks.close()
        listener.close()
    lines = [r.getMessage() for r in caplog.records if "not subscribed" in r.getMessage()]
    assert len(lines) == 1 and lines[0].startswith("ros2.grasp/arm/joint_states: not subscribed (no SROS2)"), lines


def test_a_node_rclpy_refuses_is_one_line(caplog):
    from runtime.ros2 import open_ros2_sink

    with caplog.at_level(logging.ERROR, logger="handover.ros2"):
        assert open_ros2_sink(Ros2Config(namespace="/bad-name"), side=None) is None
    assert len(caplog.records) == 1 and "cannot start the ROS 2 node" in caplog.text


def test_pad_image_rows_and_columns_follow_the_layout():
    from builtin_interfaces.msg import Time

    from firmware_io.layout import SensorLayout
    from runtime.ros2_node import pad_image, pad_topic

    layout = SensorLayout.sdh2()
    values = np.arange(layout.n_taxels, dtype=np.uint16)
    img = pad_image(layout, 3, values, Time())
    pixels = np.frombuffer(bytes(img.data), dtype=np.uint16).reshape(img.height, img.width)
    sl = layout.matrix_slice(3)
    assert pixels[0, 1] == sl.start + 1 and pixels[1, 0] == sl.start + 6  # x (column) fastest, as on the wire
    full = np.full(layout.n_taxels, 4095, dtype=np.uint16)
    bright = np.frombuffer(bytes(pad_image(layout, 0, full, Time(), gain=16).data), dtype=np.uint16)
    assert bright.max() == 4095 * 16 and full.max() == 4095  # a scaled copy; the frame is untouched
    assert [pad_topic(layout, i) for i in range(6)] == [f"pads/{t}" for t in PAD_TOPICS]


def test_a_reload_replaces_the_node_and_events_keep_flowing(tmp_path):
    from runtime.config import load_config
    from runtime.model import load_model

    models = tmp_path / "models"
    config = tmp_path / "h.toml"
    daemon_config(tmp_path, "sim://", {})  # writes the model
    config.write_text(f'[device]\nurl = "sim://"\n[model]\nfolder = "{models}"\n'
                      '[sinks]\nstdout = false\nros2 = true\n[ros2]\nnamespace = "/one"\n')
    daemon = Daemon(load_config(config))
    first = ros_sink(daemon)
    config.write_text(config.read_text().replace('"/one"', '"/two"'))
    daemon.reload()  # what SIGHUP does between two frames
    listener = Listener("/two")
    try:
        second = ros_sink(daemon)
        assert second is not first and not first._context.ok() and second.name == "ros2:/two"
        assert wait_for(lambda: second._events.get_subscription_count() >= 1)
        model = load_model(models / "m.onnx")
        daemon.sinks.emit(ModelAnnouncement.of(model, 1, None))
        assert wait_for(lambda: len(listener.events) == 1, 5.0)
        assert json.loads(listener.events[0])["model_id"] == model.model_id
    finally:
        daemon.sinks.close()
        listener.close()


def test_the_service_with_ros2_stops_on_sigterm_within_a_second(tmp_path):
    """rclpy installs no signal handlers of its own here: SIGHUP reloads, SIGTERM ends the daemon."""
    daemon_config(tmp_path, "sim://", {})  # writes the model
    cfg = tmp_path / "h.toml"
    cfg.write_text(f'[device]\nurl = "sim://?events=4&speed=4"\n[model]\nfolder = "{tmp_path / "models"}"\n'
                   '[trigger]\nfraction = 0.02\nhysteresis = 0.01\n[sinks]\nros2 = true\n[ros2]\npads = true\n')
    proc = subprocess.Popen([sys.executable, "-m", "runtime.cli", "run", "--config", str(cfg)], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    err_lines: list[str] = []

    def read_until(text: str) -> None:  # a busy machine takes its time: wait for the line, not a fixed delay
        while not any(text in line for line in err_lines) and proc.poll() is None:
            err_lines.append(proc.stderr.readline())

    read_until("handover daemon ready")  # the signal handlers are installed before this line
    proc.send_signal(signal.SIGHUP)
    read_until("configuration reloaded")
    stop_s = sigterm_seconds(proc)
    out, err = proc.communicate()
    err = "".join(err_lines) + err
    assert proc.returncode == 0 and stop_s < 1.0, (stop_s, err)
    assert "configuration reloaded" in err and err.count("ros2: node") == 2 and "Traceback" not in err, err
    lines = out.splitlines()
    assert json.loads(lines[0])["type"] == "model"
    assert all(isinstance(json.loads(line), dict) for line in lines), out  # stdout carries events only, never DDS logs


def test_a_closed_node_never_raises_into_the_daemon(tmp_path):
    daemon = Daemon(daemon_config(tmp_path, "sim://", {"pads": True}))
    sink = ros_sink(daemon)
    sink.close()
    daemon.sinks.health(daemon.health.snapshot())  # what write_health does, after the node is gone
    daemon.sinks.emit(ModelAnnouncement(time=0.0, model_id="0123456789ab", model_version=1, previous_model_id=None,
                                        model_file="m.onnx", classes=["pull"]))
    assert sink.errors == 1 and sink.sent == 0
    sink.close()  # twice is harmless


def test_two_daemons_on_one_namespace_are_told_and_the_health_view_says_so(tmp_path, caplog):
    """Both publish on /handover/events: each sees the other on the graph and says so (one warning
    line, the health view's error); a daemon alone on its namespace says nothing."""
    first = Daemon(daemon_config(tmp_path / "a", "sim://?realtime=0", {}))
    second = Daemon(daemon_config(tmp_path / "b", "sim://?realtime=0", {}))
    alone = Daemon(daemon_config(tmp_path / "c", "sim://?realtime=0", {"namespace": "/other"}))
    try:
        with caplog.at_level(logging.WARNING, logger="handover.ros2"):
            def told() -> bool:
                for d in (first, second, alone):
                    d.write_health()
                return all(ros_sink(d).problem is not None for d in (first, second))
            assert wait_for(told, 20.0), "the other daemon on /handover was never seen"
        assert "/handover/events (another daemon on this namespace?)" in first.health.last_error
        assert caplog.text.count("other publisher(s) on /handover/events") == 2
        assert ros_sink(alone).problem is None and "ros2" not in alone.health.last_error
    finally:
        for d in (first, second, alone):
            d.sinks.close()
