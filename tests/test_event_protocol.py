"""The event protocol (docs/EVENTS.md, docs/events.schema.json) against real emitted lines.

The daemon reads the simulated hand (sim://, synthetic) with toy models; a second model is
dropped mid-stream, so the stream holds both line types: model announcements (start-up and
swap) and decisions. Every line a real UDP socket receives must validate against the schema,
and every field must be documented in the schema and in docs/EVENTS.md.
"""

from __future__ import annotations

import json
import socket
import time
from pathlib import Path

import pytest

from runtime.config import config_from_dict
from runtime.daemon import Daemon
from runtime.instance_name import default_instance
from runtime.sinks import PROTOCOL_VERSION
from tests.ros2_helpers import TRIGGER, drain, run_until, udp_socket
from tests.tiny_models import CLASSES, tiny_model_bytes, write_model

pytest.importorskip("onnx")
ROOT = Path(__file__).resolve().parents[1]
SCHEMA = json.loads((ROOT / "docs" / "events.schema.json").read_text())
DOC = (ROOT / "docs" / "EVENTS.md").read_text()


def _bias(cls: str) -> tuple[float, ...]:
    return tuple(1.0 if c == cls else 0.0 for c in CLASSES)


def emitted_lines(tmp_path: Path) -> list[str]:
    """Lines the daemon sent to a real UDP socket: announcement, decisions, swap, decisions."""
    models = tmp_path / "models"
    models.mkdir()
    write_model(models, "first.onnx", tiny_model_bytes(bias=_bias("pull")), mtime=time.time() - 10)
    udp = udp_socket()
    udp.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    cfg = config_from_dict({
        "device": {"url": "sim://?seed=0&events=6&realtime=0&loop=0", "reconnect_min_s": 0.05},
        "model": {"folder": str(models), "poll_interval_s": 0.05}, "trigger": TRIGGER,
        "sinks": {"stdout": False, "udp": [f"127.0.0.1:{udp.getsockname()[1]}"]}})

    def on_event(_event) -> None:
        if daemon.health.events == 2:
            write_model(models, "second.onnx", tiny_model_bytes(bias=_bias("push")))
            deadline = time.monotonic() + 10  # hold the stream until the watcher has it ready
            while daemon.models.watcher.pending is None and time.monotonic() < deadline:
                time.sleep(0.01)

    daemon = Daemon(cfg, on_event=on_event)
    run_until(daemon, lambda d: d.health.device_faults >= 1, timeout=30)
    lines = drain(udp)
    udp.close()
    return lines


@pytest.fixture(scope="module")
def lines(tmp_path_factory) -> list[dict]:
    return [json.loads(line) for line in emitted_lines(tmp_path_factory.mktemp("events"))]


def test_real_lines_validate_against_the_schema(lines):
    jsonschema = pytest.importorskip("jsonschema")
    jsonschema.Draft202012Validator.check_schema(SCHEMA)
    for line in lines:
        jsonschema.validate(line, SCHEMA)
    types = [line["type"] for line in lines]
    assert types[0] == "model" and types.count("model") == 2 and types.count("decision") >= 4
    assert all(line["protocol"] == PROTOCOL_VERSION for line in lines)
    # every line names the daemon: the config sets none, so <host>:<device> (the simulated hand's: sim)
    assert {line["instance"] for line in lines} == {default_instance("sim://")} and default_instance("sim://").endswith(":sim")


def test_the_swap_is_announced_before_the_new_models_decisions(lines):
    models = [line for line in lines if line["type"] == "model"]
    assert [m["model_version"] for m in models] == [1, 2]
    assert models[0]["previous_model_id"] is None and models[1]["previous_model_id"] == models[0]["model_id"]
    assert [m["model_file"] for m in models] == ["first.onnx", "second.onnx"]
    serving = None
    for line in lines:  # every decision carries the model announced last
        if line["type"] == "model":
            serving = line["model_id"]
        else:
            assert line["model_id"] == serving


def test_every_field_is_documented(lines):
    for line in lines:
        documented = SCHEMA["$defs"][line["type"]]["properties"]
        assert set(line) == set(documented), line
        for key in line:
            assert f"`{key}`" in DOC, f"docs/EVENTS.md does not explain {key}"


def test_a_bad_line_is_refused_by_the_schema(lines):
    jsonschema = pytest.importorskip("jsonschema")
    decision = next(line for line in lines if line["type"] == "decision")
    for broken in ({**decision, "latency_us": "fast"}, {k: v for k, v in decision.items() if k != "class"},
                   {**decision, "model_id": "not-hex"}, {**decision, "type": "model"}):
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(broken, SCHEMA)


def test_a_line_of_a_type_not_defined_yet_validates_as_the_protocol_says():
    """Listeners skip types they do not know (docs/EVENTS.md), so the schema must not refuse them;
    known types are still held to their definition, and type and protocol stay required."""
    jsonschema = pytest.importorskip("jsonschema")
    jsonschema.Draft202012Validator.check_schema(SCHEMA)
    jsonschema.validate({"type": "heartbeat", "protocol": 1}, SCHEMA)
    jsonschema.validate({"type": "heartbeat", "protocol": 1, "uptime_s": 12.5}, SCHEMA)
    for refused in ({"type": "decision", "protocol": 1}, {"type": "model", "protocol": 1, "model_id": "x"},
                    {"protocol": 1}, {"type": "heartbeat"}, {"type": 3, "protocol": 1}):
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(refused, SCHEMA)
