"""Events reach a real UDP socket and a real Unix datagram socket; a dead sink is never fatal."""

from __future__ import annotations

import io
import json
import logging
import os
import socket

import pytest

from runtime.config import SinksConfig
from runtime.sinks import Event, SinkSet, StdoutSink, UdpSink, UnixDatagramSink
from tests.datagrams import abstract_listener


def _event() -> Event:
    return Event(time=1.5, cls="pull", scores={"pull": 3.2, "push": 0.1}, latency_us=412.3, model_id="m1",
                 frame_first=10, frame_last=24, device_time_ms=777)


def test_json_has_the_documented_fields():
    d = json.loads(_event().to_json())
    assert d["class"] == "pull" and d["model_id"] == "m1"
    assert d["frame_first"] == 10 and d["frame_last"] == 24
    assert d["latency_us"] == 412.3 and d["scores"]["pull"] == 3.2 and d["time"] == 1.5


def test_udp_and_unix_and_stdout_deliver(tmp_path):
    udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    udp.bind(("127.0.0.1", 0))
    udp.settimeout(2)
    path = tmp_path / "events.sock"
    unix = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    unix.bind(str(path))
    unix.settimeout(2)
    out = io.StringIO()
    cfg = SinksConfig(stdout=True, udp=(f"127.0.0.1:{udp.getsockname()[1]}",), unix=(str(path),))
    sinks = SinkSet.from_config(cfg, stream=out)
    sinks.emit(_event())
    sinks.emit(_event())
    for sock in (udp, unix):
        for _ in range(2):
            assert json.loads(sock.recv(65536))["class"] == "pull"
    assert [json.loads(line)["frame_last"] for line in out.getvalue().splitlines()] == [24, 24]
    assert sinks.errors == 0
    sinks.close()
    udp.close()
    unix.close()


def test_abstract_unix_socket():
    with abstract_listener("handover-test") as (address, sock):
        sink = UnixDatagramSink(address)
        sink.send("x", b'{"a":1}')
        assert sock.recv(100) == b'{"a":1}'


def test_a_missing_listener_is_counted_not_fatal(tmp_path, caplog):
    caplog.set_level(logging.WARNING, logger="handover.sinks")  # a daemon run earlier may have set "handover" to error
    dead = UnixDatagramSink(str(tmp_path / "nobody.sock"))
    closed = StdoutSink(io.StringIO())
    closed.stream.close()
    sinks = SinkSet([dead, closed, UdpSink("127.0.0.1", 9)])
    for _ in range(3):
        sinks.emit(_event())
    assert dead.errors == 3 and closed.errors == 3
    assert sinks.errors >= 6
    assert "nobody.sock" in caplog.text
    sinks.close()


def test_nan_or_infinite_numbers_never_reach_a_sink(caplog):
    """NaN is not JSON: the event is refused where it is serialised, counted, logged once."""
    udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    udp.bind(("127.0.0.1", 0))
    udp.settimeout(0.3)
    out = io.StringIO()
    sinks = SinkSet.from_config(SinksConfig(stdout=True, udp=(f"127.0.0.1:{udp.getsockname()[1]}",)), stream=out)
    for bad in (float("nan"), float("inf"), float("-inf")):
        event = _event()
        event.scores = {"pull": bad, "push": 0.1}
        assert sinks.emit(event) is False
    assert out.getvalue() == "" and sinks.invalid == 3
    try:
        data = udp.recv(65536)
    except TimeoutError:
        data = b""
    assert data == b""
    assert len([r for r in caplog.records if "not sent" in r.getMessage()]) == 1
    assert sinks.emit(_event()) is True
    assert json.loads(out.getvalue())["class"] == "pull"
    sinks.close()
    udp.close()


def test_decision_line_carries_every_event_field():
    """to_json spells the fields out (no asdict on the hot path): a new Event field must reach the line."""
    import dataclasses
    import json as _json

    from runtime.sinks import Event

    event = Event(1.5, "pull", {"pull": 0.25, "push": -1.0}, 12.34, "abc", 3, 17, 99, True)
    line = _json.loads(event.to_json())
    fields = {f.name for f in dataclasses.fields(Event)} - {"cls"} | {"class", "type", "protocol"}
    assert set(line) == fields
    assert line["class"] == "pull" and line["latency_us"] == 12.3 and line["missed_deadline"] is True


class _Str(str):
    pass


class _Int(int):
    pass


def _reference_line(e: Event) -> str:
    """The documented line as the json module writes it (what ``to_json`` must equal)."""
    d = {"type": "decision", "protocol": 1, "instance": e.instance, "class": e.cls, "time": e.time,
         "scores": {k: round(float(v), 6) for k, v in e.scores.items()}, "latency_us": round(float(e.latency_us), 1),
         "model_id": e.model_id, "frame_first": e.frame_first, "frame_last": e.frame_last,
         "device_time_ms": e.device_time_ms, "missed_deadline": e.missed_deadline}
    return json.dumps(d, separators=(",", ":"), allow_nan=False)


def test_event_line_is_the_json_modules_character_for_character():
    """The hot path writes plain events itself; any odd value goes to the encoder, errors included."""
    import numpy as np

    rng = np.random.default_rng(0)
    names = ["pull", "k\u00e9y \"q\" \\ \n\t\x01", "\U0001f600", _Str("sub")]
    odd = {"cls": [*names[1:], None], "time": [0.0, -0.0, 1e300, 5e-324, 1e16, 0.1 + 0.2, 7, True, _Int(3)],
           "model_id": [*names[1:], 3], "frame_first": [0, -1, 2**70, _Int(5), True, 1.5],
           "device_time_ms": [0, 2**33, False], "missed_deadline": [True, False, 0, 1],
           "scores": [{}, {"a": 1}, {"a": True}, {_Str("s"): 0.5}, {1: 0.5}, {"x": 1e-7, "y": -2.5e-7, "z": 1e17}],
           "latency_us": [0, 1e9, 0.05, 2.25], "instance": ["", "left-hand", *names[1:], None]}
    for field, values in odd.items():
        for value in values:
            event = _event()
            setattr(event, field, value)
            assert event.to_json() == _reference_line(event), (field, value)
    for _ in range(200):
        scores = dict(zip(names, rng.normal(0, 10.0 ** rng.integers(-8, 8), 4).tolist(), strict=True))
        event = Event(float(rng.random() * 2e9), names[rng.integers(4)], scores, float(rng.random() * 1e5),
                      "39f8d4c0dfa9", int(rng.integers(1e6)), int(rng.integers(1e6)), int(rng.integers(2**32)),
                      bool(rng.integers(2)))
        assert event.to_json() == _reference_line(event)
    for field, bad in (("time", float("nan")), ("time", float("inf")), ("frame_first", np.int64(3)),
                       ("scores", {"a": float("nan")}), ("scores", {"a": float("-inf")}), ("cls", object()),
                       ("latency_us", float("inf")), ("time", np.float32(1.0))):
        event = _event()
        setattr(event, field, bad)
        with pytest.raises((ValueError, TypeError)) as ours:
            event.to_json()
        with pytest.raises((ValueError, TypeError)) as reference:
            _reference_line(event)
        assert type(ours.value) is type(reference.value) and str(ours.value) == str(reference.value)


def test_event_line_is_the_documented_dict_encoded():
    event = Event(1795482290.0698714, "pull", {"pull": 1 / 3, "push": -2.5e-7, "h\u00f6ld": 7.0}, 1033.449, "39f8d4c0dfa9",
                  179, 193, 6091, False, "robot-pc:ttyUSB0")
    expected = {"type": "decision", "protocol": 1, "instance": "robot-pc:ttyUSB0", "class": "pull",
                "time": 1795482290.0698714,
                "scores": {"pull": 0.333333, "push": -0.0, "h\u00f6ld": 7.0}, "latency_us": 1033.4,
                "model_id": "39f8d4c0dfa9", "frame_first": 179, "frame_last": 193, "device_time_ms": 6091,
                "missed_deadline": False}
    assert event.to_json() == json.dumps(expected, separators=(",", ":"), allow_nan=False)


def test_stdout_lines_the_reader_never_took_are_counted_and_said_at_stop(caplog):
    """A pipe nobody reads: at close every waiting line is counted as dropped, in one warning."""
    read_end, write_end = os.pipe()
    sink = StdoutSink(os.fdopen(write_end, "w"))
    line = '{"type":"decision","pad":"' + "x" * 90 + '"}'
    for _ in range(1000):  # 100 KB: more than the pipe takes, less than the backlog
        sink.send(line, line.encode())
    assert sink.dropped == 0
    with caplog.at_level(logging.WARNING, logger="handover.sinks"):
        sink.close()
    os.set_blocking(read_end, False)
    delivered = os.read(read_end, 1 << 20).decode().count("\n")
    os.close(read_end)
    assert 0 < delivered < 1000 and delivered + sink.dropped == 1000
    said = [r.getMessage() for r in caplog.records if "dropped at stop" in r.getMessage()]
    assert len(said) == 1 and said[0].startswith(f"sink stdout: {1000 - delivered} event lines")
