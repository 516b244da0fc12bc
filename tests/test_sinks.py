"""Events reach a real UDP socket and a real Unix datagram socket; a dead sink is never fatal."""

from __future__ import annotations

import io
import json
import socket

from runtime.config import SinksConfig
from runtime.sinks import Event, SinkSet, StdoutSink, UdpSink, UnixDatagramSink


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
    name = f"handover-test-{id(object())}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    sock.settimeout(2)
    sink = UnixDatagramSink("@" + name)
    sink.send("x", b'{"a":1}')
    assert sock.recv(100) == b'{"a":1}'
    sock.close()


def test_a_missing_listener_is_counted_not_fatal(tmp_path, caplog):
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
