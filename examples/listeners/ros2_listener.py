"""Listens for handover events on ROS 2 and prints one line per event (docs/EVENTS.md).

    python3 ros2_listener.py                    # namespace /handover, forever
    python3 ros2_listener.py /lab/hand 3        # another namespace; exit after 3 events

Needs rclpy (the daemon's ros extra, or a sourced ROS 2 install) and the same ROS_DOMAIN_ID
as the daemon. Subscribes <ns>/events (std_msgs/String: the JSON line), the latched
<ns>/model (the model now serving, even if it started before this listener) and /diagnostics.
"""

import json
import sys

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String
from udp_listener import describe  # the same line per event as the UDP listener (this folder)


def main(namespace: str = "/handover", count: int = -1) -> None:
    rclpy.init()
    node = rclpy.create_node("handover_listener")
    seen = 0

    def on_event(msg: String) -> None:
        nonlocal seen
        text = describe(json.loads(msg.data))
        if text is not None:
            print(text, flush=True)
            seen += 1

    def on_model(msg: String) -> None:
        print(f"serving: {json.loads(msg.data)['model_id']}", file=sys.stderr, flush=True)

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if "handover" in status.name:
                print(f"health: {status.message}", file=sys.stderr, flush=True)

    node.create_subscription(String, f"{namespace}/events", on_event, 100)
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node.create_subscription(String, f"{namespace}/model", on_model, latched)
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 10)
    print(f"listening on {namespace}/events", flush=True)
    try:
        while rclpy.ok() and (count < 0 or seen < count):
            rclpy.spin_once(node, timeout_sec=0.1)
    except KeyboardInterrupt:
        pass
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == "__main__":
    args = sys.argv[1:]
    main(args[0] if args else "/handover", int(args[1]) if len(args) > 1 else -1)
