"""The ROS 2 node behind ``sinks.ros2 = true``: events, health, live pads, the grasp input.

Topics (``ns`` = ``[ros2] namespace``, default ``/handover``):

- ``ns/events``  std_msgs/String: exactly the JSON line the other sinks send (docs/EVENTS.md);
- ``ns/model``   std_msgs/String, latched (transient local, depth 1): the last ``"type": "model"`` line;
- ``/diagnostics`` diagnostic_msgs/DiagnosticArray: the health view, about once a second;
- ``ns/pads/<pad>`` sensor_msgs/Image mono16, one per pad (optional);
- ``ns/grasp``   std_msgs/String ``closed`` / ``open`` -> ``commands.set_grasp`` (optional);
- ``ns/arm``     std_msgs/String ``moving`` / ``still`` -> ``commands.set_arm_moving`` (optional);
- ``ns/outcome`` std_msgs/String ``taken`` / ``kept`` / ``dropped`` / a class -> ``commands.outcome`` (optional);
- ``[ros2] joint_states`` sensor_msgs/JointState: moving while a joint is faster than ``joint_speed``.

The node sees only a ``DaemonSide`` (runtime.sinks). Events are published on the daemon's thread;
everything else runs on one executor thread, so the hot path never waits on a subscriber.
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import Image, JointState
from std_msgs.msg import String

from runtime.arm_motion import JointSpeed
from runtime.config import Ros2Config
from runtime.ros2 import namespace_clash
from runtime.sinks import DaemonSide, Sink

__all__ = ["Ros2Sink", "log", "pad_image", "pad_topic"]

log = logging.getLogger("handover.ros2")

GRASP_WORDS = {"closed": True, "open": False}
"""What ``ns/grasp`` accepts (case and surrounding blanks ignored)."""
ARM_WORDS = {"moving": True, "still": False}
"""What ``ns/arm`` accepts (case and surrounding blanks ignored)."""
DIAGNOSTICS_TOPIC = "/diagnostics"
_MODEL_PREFIX = '{"type":"model"'
_LEVELS = {"streaming": DiagnosticStatus.OK, "stopped": DiagnosticStatus.STALE, "failed": DiagnosticStatus.ERROR}
_RELIABILITY = {"reliable": ReliabilityPolicy.RELIABLE, "best_effort": ReliabilityPolicy.BEST_EFFORT}
_DURABILITY = {"volatile": DurabilityPolicy.VOLATILE, "transient_local": DurabilityPolicy.TRANSIENT_LOCAL}


def pad_topic(layout: Any, index: int) -> str:
    """``pads/finger_0_distal``, ``pads/thumb_proximal`` ... (ROS names take no ``-``)."""
    name = layout.pad_name(index).replace("-", "_")
    return f"pads/{'pad_' + name if name[0].isdigit() else name}"


def pad_image(layout: Any, index: int, values: Any, stamp: Any, gain: int = 1) -> Image:
    """One pad of a frame as a mono16 image: rows x columns as on the pad, taxel values x gain."""
    m = layout.matrices[index]
    img = Image()
    img.header.stamp = stamp
    img.header.frame_id = pad_topic(layout, index).removeprefix("pads/")
    img.height, img.width = m.cells_y, m.cells_x
    img.encoding = "mono16"
    img.is_bigendian = int(sys.byteorder == "big")
    img.step = 2 * m.cells_x
    pad = values[layout.matrix_slice(index)]
    img.data = (pad if gain == 1 else pad * np.uint16(gain)).tobytes()  # gain <= 16: 4095 x 16 fits
    return img


def diagnostic_status(snapshot: dict, name: str, hardware_id: str) -> DiagnosticStatus:
    """The health view as one DiagnosticStatus; every counter is a key/value pair."""
    state = str(snapshot.get("device_state", "unknown"))
    level = _LEVELS.get(state, DiagnosticStatus.WARN)
    if level == DiagnosticStatus.OK and not snapshot.get("model_id"):
        level = DiagnosticStatus.WARN
    message = f"{state}; {snapshot.get('frame_rate_hz', 0)} frames/s; model {snapshot.get('model_id') or 'none'}"
    if snapshot.get("instance"):
        message = f"{snapshot['instance']}: {message}"
    if level != DiagnosticStatus.OK and snapshot.get("last_error"):
        message += f"; {snapshot['last_error']}"
    values = dict(snapshot)
    values["model_swaps"] = max(0, int(snapshot.get("models_loaded", 0)) - 1)
    return DiagnosticStatus(level=level, name=name, message=message, hardware_id=hardware_id,
                            values=[KeyValue(key=k, value="" if v is None else str(v)) for k, v in values.items()])


class Ros2Sink(Sink):
    """One rclpy node in its own context, so the daemon's signal handlers stay its own."""

    failures = (Exception,)  # rclpy raises its own types; none may reach the hot path

    def __init__(self, cfg: Ros2Config, side: DaemonSide | None) -> None:
        super().__init__()
        self.name = f"ros2:{cfg.namespace}"
        self.cfg = cfg
        self.side = side
        self.pad_images = 0
        """Images published on the pad topics so far (to at least one subscriber)."""
        self._snapshot: dict | None = None
        self._pad_frame: Any = None
        self._pad_layout: Any = None
        self._pad_publishers: list[tuple[int, Any]] = []
        self._last_warning = 0.0
        self._context = Context()
        rclpy.init(context=self._context, args=["--ros-args", "--disable-external-lib-logs"],
                   signal_handler_options=SignalHandlerOptions.NO)
        try:
            self._build_node()
        except Exception:
            self._context.try_shutdown()
            raise
        self._thread = threading.Thread(target=self._spin, name="handover-ros2", daemon=True)
        self._thread.start()
        log.info("ros2: node %s/%s publishes %s/events and %s%s%s", cfg.namespace.rstrip("/"), cfg.node_name,
                 cfg.namespace, DIAGNOSTICS_TOPIC, f", {cfg.namespace}/pads/* at {cfg.pad_rate_hz:g} Hz" if cfg.pads
                 else "", self._listens())

    def _listens(self) -> str:
        cfg = self.cfg
        topics = [f"{cfg.namespace}/{t}" for t, on in (("grasp", cfg.grasp), ("arm", cfg.arm), ("outcome", cfg.outcome))
                  if on]
        if cfg.joint_states:
            topics.append(f"{cfg.joint_states} (joint speed > {cfg.joint_speed:g})")
        return f"; listens on {', '.join(topics)}" if topics else ""

    def _build_node(self) -> None:
        cfg = self.cfg
        node = self.node = rclpy.create_node(cfg.node_name, namespace=cfg.namespace, context=self._context)
        reliability = _RELIABILITY[cfg.reliability]
        events_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=cfg.depth, reliability=reliability,
                                durability=_DURABILITY[cfg.durability])
        self._events = node.create_publisher(String, "events", events_qos)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self._model = node.create_publisher(String, "model", latched)
        self._diagnostics = node.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, 10)
        self._pad_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=reliability)
        self._health_signal = node.create_guard_condition(self._publish_health)
        if cfg.pads:
            node.create_timer(1.0 / cfg.pad_rate_hz, self._publish_pads)
        if cfg.grasp:
            node.create_subscription(String, "grasp", self._on_grasp, 10)
        if cfg.arm:
            node.create_subscription(String, "arm", self._on_arm, 10)
        if cfg.outcome:
            node.create_subscription(String, "outcome", self._on_outcome, 10)
        if cfg.joint_states:
            self._joints = JointSpeed(cfg.joint_speed)
            node.create_subscription(JointState, cfg.joint_states, self._on_joints, 10)
        self._executor = SingleThreadedExecutor(context=self._context)
        self._executor.add_node(node)

    # -- the daemon's thread ----------------------------------------------------------------------
    def _send(self, line: str, data: bytes) -> None:
        msg = String(data=line)
        self._events.publish(msg)
        if line.startswith(_MODEL_PREFIX):
            self._model.publish(msg)

    def health(self, snapshot: dict) -> None:
        self._snapshot = snapshot
        try:
            self._health_signal.trigger()  # the executor's thread publishes it
        except Exception as exc:  # a node that is gone must not reach the hot path
            self._warn(f"ros2: diagnostics not published ({exc})")

    def close(self) -> None:
        """Publish the last health view, then stop the executor and the node."""
        if not self._context.ok():
            return
        self._publish_health()
        self._executor.shutdown(timeout_sec=1.0)
        self._context.try_shutdown()
        self._thread.join(timeout=1.0)
        self.node.destroy_node()

    # -- the executor's thread --------------------------------------------------------------------
    def _spin(self) -> None:
        try:
            self._executor.spin()
        except ExternalShutdownException:
            pass
        except Exception as exc:  # the node is gone; events still reach the other sinks
            log.error("ros2: the node stopped (%s); health and pads are no longer published", exc)

    def _publish_health(self) -> None:
        snapshot = self._snapshot
        if snapshot is None:
            return
        self._check_namespace()
        try:
            msg = DiagnosticArray()
            msg.header.stamp = self.node.get_clock().now().to_msg()
            name = f"{self.cfg.node_name}: tactile handover"
            msg.status = [diagnostic_status(snapshot, name, self.side.hardware_id if self.side else "")]
            self._diagnostics.publish(msg)
        except Exception as exc:
            self._warn(f"ros2: diagnostics not published ({exc})")

    def _check_namespace(self) -> None:
        """Another publisher on our events topic: one warning line, and ``problem`` while it lasts (the daemon
        shows it in the health view)."""
        try:
            clash = namespace_clash(self.node.count_publishers(self._events.topic_name), self.cfg.namespace)
        except Exception:  # a node being shut down
            return
        if clash is not None and clash != self.problem:
            log.warning("%s", clash)
        self.problem = clash

    def _publish_pads(self) -> None:
        if self.side is None:
            return
        frame, layout = self.side.frames.latest_frame, self.side.frames.layout
        if frame is None or layout is None or frame is self._pad_frame:
            return  # nothing new: publish nothing rather than the same image again
        self._pad_frame = frame
        try:  # an exception here would end the executor: health, pads and the grasp topic with it
            if layout is not self._pad_layout:
                for _, pub in self._pad_publishers:
                    self.node.destroy_publisher(pub)
                self._pad_layout = layout
                self._pad_publishers = [(i, self.node.create_publisher(Image, pad_topic(layout, i), self._pad_qos))
                                        for i in range(layout.n_matrices)]
            stamp = self.node.get_clock().now().to_msg()
            for index, pub in self._pad_publishers:
                if pub.get_subscription_count():  # nobody looking: no image built
                    pub.publish(pad_image(layout, index, frame.values, stamp, self.cfg.pad_gain))
                    self.pad_images += 1
        except Exception as exc:
            self._warn(f"ros2: pad images not published ({exc})")

    def _word(self, msg: String, topic: str, words: dict[str, bool]) -> str | None:
        """The message's word if ``words`` has it (case and blanks ignored); else one warning and None."""
        word = msg.data.strip().lower()
        if word in words:
            return word
        expected = " or ".join(repr(w) for w in words)
        self._warn(f"ros2: {self.cfg.namespace}/{topic}: expected {expected}, got {msg.data[:40]!r}; ignored")
        return None

    def _on_grasp(self, msg: String) -> None:
        word = self._word(msg, "grasp", GRASP_WORDS)
        if word is None:
            return
        try:
            self.side.commands.set_grasp(GRASP_WORDS[word], source="ros2")
        except Exception as exc:
            self._warn(f"ros2: grasp {word!r} not taken ({exc})")

    def _on_arm(self, msg: String) -> None:
        word = self._word(msg, "arm", ARM_WORDS)
        if word is not None:
            self._set_arm(ARM_WORDS[word])

    def _on_outcome(self, msg: String) -> None:
        """The word is checked by field capture (runtime.capture: one line for an unknown one)."""
        try:
            self.side.commands.outcome(msg.data.strip().lower()[:64], source="ros2")
        except Exception as exc:
            self._warn(f"ros2: outcome {msg.data[:40]!r} not taken ({exc})")

    def _on_joints(self, msg: JointState) -> None:
        try:
            stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            moving = self._joints.update(list(msg.position), list(msg.velocity), stamp or time.monotonic())
        except Exception as exc:  # a malformed message must not end the executor
            self._warn(f"ros2: {self.cfg.joint_states}: joint state not read ({exc})")
            return
        if moving is not None:
            self._set_arm(moving)

    def _set_arm(self, moving: bool) -> None:
        try:
            self.side.commands.set_arm_moving(moving, source="ros2")
        except Exception as exc:
            self._warn(f"ros2: arm {'moving' if moving else 'still'} not taken ({exc})")

    def _warn(self, text: str) -> None:
        now = time.monotonic()
        if now - self._last_warning > 10.0:  # a chatty or broken peer must not flood the journal
            self._last_warning = now
            log.warning("%s", text)
