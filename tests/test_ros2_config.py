"""The ROS 2 sink's configuration and its failures: none of these needs rclpy.

A ROS problem (rclpy missing, a middleware that cannot load, a domain id out of range) is
one log line; the daemon keeps sending events to its other sinks (here a real UDP socket).
"""

from __future__ import annotations

import json
import logging
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from runtime.config import ConfigError, Ros2Config, config_from_dict
from runtime.daemon import Daemon
from runtime.ros2 import middleware_problem
from tests.ros2_helpers import daemon_config, drain, ros_sink, run_until, udp_socket
from tests.tiny_models import tiny_model_bytes, write_model

ROOT = Path(__file__).resolve().parents[1]


def test_ros2_is_off_by_default_and_the_section_has_defaults():
    cfg = config_from_dict({})
    assert cfg.sinks.ros2 is False and cfg.ros2 == Ros2Config()
    assert (cfg.ros2.namespace, cfg.ros2.pads, cfg.ros2.grasp) == ("/handover", False, False)
    cfg = config_from_dict({"sinks": {"ros2": True}, "ros2": {"namespace": "/lab/hand_1", "pads": True,
                                                             "pad_rate_hz": 32, "reliability": "best_effort",
                                                             "durability": "transient_local", "depth": 50}})
    assert cfg.sinks.ros2 and cfg.ros2.namespace == "/lab/hand_1" and cfg.ros2.pad_rate_hz == 32.0


@pytest.mark.parametrize("section, says", [
    ({"namespace": "handover"}, "ros2.namespace"),
    ({"namespace": "/hand-over"}, "ros2.namespace"),
    ({"namespace": "/a//b"}, "ros2.namespace"),
    ({"namespace": "/"}, "ros2.namespace"),
    ({"node_name": "1st"}, "ros2.node_name"),
    ({"reliability": "sometimes"}, "ros2.reliability: must be one of reliable, best_effort"),
    ({"durability": "forever"}, "ros2.durability: must be one of volatile, transient_local"),
    ({"depth": 0}, "ros2.depth: must be a finite number in [1, 10000], got 0"),
    ({"pad_rate_hz": 0}, "ros2.pad_rate_hz: must be a finite number in [0.1, 1000], got 0"),
    ({"pads": "yes"}, "ros2.pads: must be true or false"),
    ({"pad_gain": 17}, "ros2.pad_gain: must be a finite number in [1, 16], got 17"),
    ({"pad_rate_hz": float("nan")}, "ros2.pad_rate_hz: must be a finite number in [0.1, 1000], got nan"),
    ({"qos": "reliable"}, "ros2.qos: unknown key"),
    ({"joint_states": "///joint_states"}, "ros2.joint_states: must be a topic name"),
    ({"joint_states": "/" + "j" * 247}, "ros2.joint_states: /jjjj"),
    ({"joint_states": "j" * 238}, "ros2.joint_states: /handover/jjj"),
])
def test_bad_ros2_keys_name_the_key(section, says):
    with pytest.raises(ConfigError, match="^" + re.escape(says)):
        config_from_dict({"sinks": {"ros2": True}, "ros2": section})


@pytest.mark.parametrize("env, says", [
    ({}, None),
    ({"ROS_DOMAIN_ID": "42"}, None),
    ({"ROS_DOMAIN_ID": "233"}, "ROS_DOMAIN_ID='233' must be a number from 0 to 232"),
    ({"ROS_DOMAIN_ID": "one"}, "ROS_DOMAIN_ID='one'"),
    ({"RMW_IMPLEMENTATION": "fastdds"}, "is not a middleware name"),
    ({"RMW_IMPLEMENTATION": "rmw_nowhere_cpp"}, "librmw_nowhere_cpp.so is not installed"),
])
def test_middleware_problem(env, says):
    problem = middleware_problem(env)
    assert problem is None if says is None else says in problem


def _run_with_udp(tmp_path: Path, caplog) -> list[str]:
    udp = udp_socket()
    cfg = daemon_config(tmp_path, "sim://?seed=0&events=3&realtime=0&loop=0", {}, udp.getsockname()[1])
    with caplog.at_level(logging.INFO, logger="handover"):
        daemon = Daemon(cfg)
        run_until(daemon, lambda d: d.health.events >= 2)
    lines = drain(udp)
    udp.close()
    assert ros_sink(daemon) is None
    assert [json.loads(x)["type"] for x in lines].count("decision") >= 2, "UDP kept delivering"
    return [r.getMessage() for r in caplog.records if r.name == "handover.ros2"]


def test_rclpy_missing_is_one_line_and_udp_keeps_delivering(tmp_path, caplog, monkeypatch):
    pytest.importorskip("onnx")
    monkeypatch.setitem(sys.modules, "rclpy", None)  # what an install without the ros extra sees
    monkeypatch.delitem(sys.modules, "runtime.ros2_node", raising=False)
    messages = _run_with_udp(tmp_path, caplog)
    assert len(messages) == 1 and "rclpy" in messages[0] and "tactile-handover[ros]" in messages[0], messages


@pytest.mark.parametrize("env, says", [
    ({"RMW_IMPLEMENTATION": "rmw_nowhere_cpp"}, "librmw_nowhere_cpp.so is not installed"),
    ({"ROS_DOMAIN_ID": "500"}, "ROS_DOMAIN_ID='500'"),
])
def test_a_middleware_that_cannot_load_is_one_line(tmp_path, caplog, monkeypatch, env, says):
    """Checked before rclpy loads it: ROS 2's C library would end the process (exit 102)."""
    pytest.importorskip("onnx")
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    messages = _run_with_udp(tmp_path, caplog)
    assert len(messages) == 1 and says in messages[0], messages


def _config_with_model(tmp_path: Path, sinks: str) -> Path:
    """A config whose model folder holds one toy model, with these ``[sinks]`` lines."""
    pytest.importorskip("onnx")
    models = tmp_path / "models"
    models.mkdir()
    write_model(models, "m.onnx", tiny_model_bytes())
    cfg = tmp_path / "h.toml"
    cfg.write_text(f'[device]\nurl = "sim://"\n[model]\nfolder = "{models}"\n[sinks]\n{sinks}')
    return cfg


def test_check_reports_a_ros2_problem_without_starting_a_node(tmp_path):
    cfg = _config_with_model(tmp_path, "ros2 = true\n")
    code = ("import sys; from runtime.cli import main; rc = main(['run', '--config', sys.argv[1], '--check']);"
            "print('RCLPY', 'rclpy' in sys.modules); sys.exit(rc)")
    env = {**os.environ, "RMW_IMPLEMENTATION": "rmw_nowhere_cpp"}
    proc = subprocess.run([sys.executable, "-c", code, str(cfg)], cwd=ROOT, capture_output=True, text=True,
                          timeout=60, env=env)
    assert proc.returncode == 0 and "RCLPY False" in proc.stdout, proc.stdout + proc.stderr
    warnings = [line for line in proc.stderr.splitlines() if "sinks.ros2" in line]
    assert len(warnings) == 1 and "librmw_nowhere_cpp.so is not installed" in warnings[0], proc.stderr


def test_ros2_as_the_only_sink_says_events_go_nowhere(tmp_path, caplog, monkeypatch):
    """stdout = false and ros2 = true where ROS 2 cannot start: the line said `events still go to
    the other sinks`, and there were none."""
    from runtime.config import config_from_dict
    from runtime.sinks import SinkSet

    monkeypatch.setitem(sys.modules, "rclpy", None)
    monkeypatch.delitem(sys.modules, "runtime.ros2_node", raising=False)
    cfg = config_from_dict({"device": {"url": "sim://"}, "model": {"folder": str(tmp_path)},
                            "sinks": {"stdout": False, "ros2": True}})
    with caplog.at_level(logging.ERROR, logger="handover"):
        sinks = SinkSet.from_config(cfg.sinks, ros2=cfg.ros2, side=None)
    assert sinks.sinks == []
    lines = [r.getMessage() for r in caplog.records if r.name == "handover.ros2"]
    assert len(lines) == 1 and lines[0].endswith("; events go nowhere: no other sink is configured (set "
                                                 "sinks.stdout = true, or add sinks.udp or sinks.unix targets)"), lines


@pytest.mark.parametrize("sinks, says", [
    ("stdout = false\nros2 = true\n", "librmw_nowhere_cpp.so is not installed"),
    ("stdout = false\n", "sinks: events go nowhere: no sink is configured"),
])
def test_check_warns_when_no_sink_would_be_left(tmp_path, sinks, says):
    cfg = _config_with_model(tmp_path, sinks)
    env = {**os.environ, "RMW_IMPLEMENTATION": "rmw_nowhere_cpp"}
    proc = subprocess.run([sys.executable, "-m", "runtime.cli", "run", "--config", str(cfg), "--check"], cwd=ROOT,
                          capture_output=True, text=True, timeout=60, env=env)
    assert proc.returncode == 0, proc.stderr
    lines = [line for line in proc.stderr.strip().splitlines() if "warning: stream setting" not in line]
    assert len(lines) == 1 and says in lines[0] and "events go nowhere" in lines[0], proc.stderr


SROS2 = {"ROS_SECURITY_ENABLE": "true", "ROS_SECURITY_STRATEGY": "Enforce"}
LOCAL = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "ROS_DOMAIN_ID": "7"}


@pytest.mark.parametrize("trust, env, listen, says", [
    ("sros2", SROS2, True, None),
    ("sros2", LOCAL, False, "not subscribed (no SROS2): every user of this PC can send"),
    ("sros2", {"ROS_DOMAIN_ID": "7"}, False, "not subscribed (no SROS2): any ROS 2 node on the network in domain 7"),
    ("local_users", LOCAL, True, 'subscribed without SROS2 (ros2.trust = "local_users"): every user of this PC'),
    ("local_users", {}, False, 'not subscribed (ros2.trust = "local_users" but discovery is not kept to this PC)'),
    ("network", {}, True, 'subscribed without SROS2 (ros2.trust = "network"): any ROS 2 node on the network in '
                          "domain 0"),
])
def test_ros2_inputs_that_steer_detection_need_sros2_or_a_trust_that_names_who(trust, env, listen, says):
    """LOCALHOST discovery still lets every local user (uid 65534 too) send 'moving' or fast joints: without
    SROS2 the inputs are subscribed only when ros2.trust names that scope, and either way one line says so."""
    from runtime.ros2 import robot_inputs

    ros2 = config_from_dict({"ros2": {"arm": True, "joint_states": "/joint_states", "trust": trust}}).ros2
    subscribed, line = robot_inputs(ros2, env)
    assert subscribed is listen
    if says is None:
        assert line is None
    else:
        assert line.startswith("ros2.arm/joint_states: ") and says in line and "\n" not in line, line
        assert "'moving' on /handover/arm or fast joints on /joint_states" in line
    assert robot_inputs(config_from_dict({}).ros2, env) == (False, None)  # no input configured: nothing to say


def test_the_outcome_topic_is_subscribed_under_the_same_trust_and_says_what_it_could_do():
    """An outcome does not steer detection but labels the field capture (what training may learn)."""
    from runtime.ros2 import robot_inputs

    ros2 = config_from_dict({"ros2": {"outcome": True}}).ros2
    subscribed, line = robot_inputs(ros2, LOCAL)
    assert not subscribed and line.startswith("ros2.outcome: not subscribed (no SROS2)"), line
    assert "outcomes on /handover/outcome and label the field capture" in line and "trigger" not in line
    both = config_from_dict({"ros2": {"outcome": True, "grasp": True, "trust": "local_users"}}).ros2
    subscribed, line = robot_inputs(both, LOCAL)
    assert subscribed and "silence the trigger and label the field capture" in line, line


@pytest.mark.parametrize("trust, says", [("", "not subscribed (no SROS2)"),
                                         ('trust = "local_users"\n', "subscribed without SROS2")])
def test_check_says_in_one_line_whether_the_ros2_inputs_are_subscribed(tmp_path, trust, says):
    cfg = _config_with_model(tmp_path, "ros2 = true\n")
    cfg.write_text(cfg.read_text() + f"[ros2]\ngrasp = true\n{trust}")
    env = {**os.environ, **LOCAL}
    env.pop("ROS_SECURITY_ENABLE", None)
    proc = subprocess.run([sys.executable, "-m", "runtime.cli", "run", "--config", str(cfg), "--check"], cwd=ROOT,
                          capture_output=True, text=True, timeout=60, env=env)
    lines = [line for line in proc.stderr.splitlines() if "ros2.grasp" in line]
    assert proc.returncode == 0 and len(lines) == 1 and says in lines[0], proc.stderr
