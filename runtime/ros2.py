"""Whether the ROS 2 sink can run here, and opening it without ever taking the daemon down.

The daemon imports this module only when ``sinks.ros2 = true``; rclpy itself is imported by
runtime/ros2_node.py, only after the checks here passed. A ROS problem (rclpy missing, an
unknown middleware, a domain id out of range) is one log line; events keep going to the
other sinks.
"""

from __future__ import annotations

import logging
import os
import re
import sys
import warnings
from dataclasses import replace
from pathlib import Path

from runtime.config import NO_SINK_LEFT, Ros2Config
from runtime.sinks import DaemonSide, Sink

__all__ = ["availability_problem", "log", "middleware_problem", "open_ros2_sink", "robot_inputs"]

log = logging.getLogger("handover.ros2")

EXTRA_HINT = "pip install 'tactile-handover[ros]' (deploy/INSTALL.md, section ROS 2)"


def middleware_problem(env: dict[str, str] | None = None) -> str | None:
    """Why the ROS 2 middleware cannot load, or None.

    Checked before rclpy is imported because ROS 2's C library ends the whole process (exit
    102) when ``RMW_IMPLEMENTATION`` names a middleware that is not installed.
    """
    env = os.environ if env is None else env
    name = env.get("RMW_IMPLEMENTATION", "").strip()
    domain = env.get("ROS_DOMAIN_ID", "").strip()
    if domain and not (domain.isdigit() and int(domain) <= 232):
        return f"ROS_DOMAIN_ID={domain!r} must be a number from 0 to 232 (0-101 is safe everywhere)"
    if not name:
        return None  # the default middleware (rmw_fastrtps_cpp with the ros extra)
    if not re.fullmatch(r"rmw_[a-z0-9_]+", name):
        return f"RMW_IMPLEMENTATION={name!r} is not a middleware name (e.g. rmw_fastrtps_cpp)"
    folders = [Path(sys.prefix) / "lib", *(Path(p) for p in env.get("LD_LIBRARY_PATH", "").split(os.pathsep) if p)]
    if any((folder / f"lib{name}.so").exists() for folder in folders):
        return None
    from ctypes.util import find_library

    if find_library(name):
        return None
    return f"RMW_IMPLEMENTATION={name}: lib{name}.so is not installed; unset RMW_IMPLEMENTATION or install that middleware"


CONFINED_RANGES = ("LOCALHOST", "OFF")
"""``ROS_AUTOMATIC_DISCOVERY_RANGE`` values that keep other machines' nodes away (ROS 2 Iron and later)."""
TRUST_HINT = ('enable SROS2 (ROS_SECURITY_ENABLE=true, ROS_SECURITY_STRATEGY=Enforce), or accept it with ros2.trust = '
              '"local_users" or "network", or use the control socket (deploy/INSTALL.md, section ROS 2)')


def robot_inputs(cfg: Ros2Config, env: dict[str, str] | None = None) -> tuple[bool, str | None]:
    """Whether the ROS 2 inputs that steer detection (grasp, arm, joint states) are subscribed, and the
    one line to say about them (None: nothing to say). The one owner of this rule (start-up, ``--check``).

    Why: ROS 2 without SROS2 asks no one who publishes; ``open`` on the grasp topic, ``moving`` on the arm
    topic or a fast joint silences the trigger. Discovery kept to this PC still trusts every local user,
    so without SROS2 (enforced) only ``ros2.trust`` naming that scope subscribes them, with a warning."""
    inputs = [text for on, text in ((cfg.grasp, f"'open' on {cfg.namespace}/grasp"),
                                    (cfg.arm, f"'moving' on {cfg.namespace}/arm"),
                                    (bool(cfg.joint_states), f"fast joints on {cfg.joint_states}"),
                                    (cfg.outcome, f"outcomes on {cfg.namespace}/outcome")) if on]
    if not inputs:
        return False, None
    env = os.environ if env is None else env
    if env.get("ROS_SECURITY_ENABLE", "").lower() == "true" and env.get("ROS_SECURITY_STRATEGY") == "Enforce":
        return True, None
    confined = (env.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").upper() in CONFINED_RANGES
                or env.get("ROS_LOCALHOST_ONLY") == "1")
    domain = env.get("ROS_DOMAIN_ID", "").strip() or "0"
    who = "every user of this PC" if confined else f"any ROS 2 node on the network in domain {domain}"
    keys = "/".join(k for k, on in (("grasp", cfg.grasp), ("arm", cfg.arm), ("joint_states", cfg.joint_states),
                                    ("outcome", cfg.outcome)) if on)
    harm = " and ".join(h for h, on in (("silence the trigger", cfg.grasp or cfg.arm or cfg.joint_states),
                                        ("label the field capture", cfg.outcome)) if on)
    can = f"{who} can send {' or '.join(inputs)} and {harm}"
    if cfg.trust == "network" or (cfg.trust == "local_users" and confined):
        return True, f'ros2.{keys}: subscribed without SROS2 (ros2.trust = "{cfg.trust}"): {can}'
    why = "no SROS2" if cfg.trust == "sros2" else 'ros2.trust = "local_users" but discovery is not kept to this PC'
    return False, f"ros2.{keys}: not subscribed ({why}): {can}; {TRUST_HINT}"


def namespace_clash(publishers: int, namespace: str) -> str | None:
    """Why the events topic is not this daemon's alone (``publishers`` counts this daemon too), or None.

    Why: two daemons on one namespace publish events nobody can tell apart, and a grasp message on
    ``<namespace>/grasp`` reaches both."""
    if publishers <= 1:
        return None
    return (f"ros2: {publishers - 1} other publisher(s) on {namespace}/events (another daemon on this namespace?): "
            "listeners cannot tell the events apart and a grasp message reaches both; give each daemon its own "
            "ros2.namespace")


def availability_problem() -> str | None:
    """Why the ROS 2 sink would not start here, found without importing rclpy (for ``--check``)."""
    from importlib.util import find_spec

    if find_spec("rclpy") is None:
        return f"rclpy is not installed; {EXTRA_HINT}"
    return middleware_problem()


def open_ros2_sink(cfg: Ros2Config, side: DaemonSide | None, others: int = 1) -> Sink | None:
    """The ROS 2 sink, or None after one error line saying why and what to do (and, when ``others``
    is 0, that events go nowhere). The robot's inputs are subscribed only as ``robot_inputs`` says."""
    problem = middleware_problem()
    listen, line = robot_inputs(cfg)
    if line:
        log.warning("%s", line)
    if not listen:
        cfg = replace(cfg, grasp=False, arm=False, joint_states=None, outcome=False)
    if problem is None:
        try:
            from runtime.ros2_node import Ros2Sink
        except ImportError as exc:
            problem = f"rclpy or a ROS 2 message package is missing ({exc}); {EXTRA_HINT}"
    if problem is None:
        try:
            with warnings.catch_warnings():  # rclpy warns (several lines) while it drops a node it refused
                warnings.simplefilter("ignore", RuntimeWarning)
                return Ros2Sink(cfg, side)
        except Exception as exc:  # rclpy raises its own types (RCLError, InvalidHandle, ...)
            text = str(exc).strip().splitlines()
            problem = f"cannot start the ROS 2 node: {text[0] if text else type(exc).__name__}"
    log.error("sink ros2: %s; %s", problem, "events still go to the other sinks" if others else NO_SINK_LEFT)
    return None
