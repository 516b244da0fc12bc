"""Two clients on one device (README "the daemon without a hand" run twice, or `handover dump` on the
device the daemon holds): the emulated controller serves the host that is connected and closes a
second one at once with a log line naming it; the refused client says another client may hold the
device; and a daemon whose link keeps dropping soon after connecting logs it as failed attempts
(first at once, then after 1, 10, 60 minutes), while its health file hears every drop."""

from __future__ import annotations

import logging

import pytest

from firmware_io.client import DSAClient
from firmware_io.emulator.device import DeviceEmulator
from firmware_io.emulator.frame_source import placeholder_session
from firmware_io.emulator.server import TcpEmulatorServer
from firmware_io.transports import DeviceUnavailable
from runtime.daemon import Daemon
from runtime.device_link import SHORT_LINK_S
from runtime.retry_notes import QUIET, RetryNotes
from tests.clocks import ManualClock
from tests.test_faults import _config
from tests.tiny_models import tiny_model_bytes, write_model

ANOTHER_CLIENT = "another client, e.g. the daemon, may hold the device"


def _client(url: str) -> DSAClient:
    return DSAClient(url, auto_reconnect=False, gap_timeout=0.5, stop_timeout=1.0, flush_quiet=0.05, flush_max=0.3)


def test_the_connected_host_keeps_the_device_and_a_second_is_refused_at_once(caplog, capsys):
    from runtime import cli

    caplog.set_level(logging.WARNING, logger="handover.emulator")
    with TcpEmulatorServer(DeviceEmulator(placeholder_session(seed=4, events=2), speed=20.0)) as server:
        first = _client(server.url)
        first.open()
        first.start()
        assert first.read_frame(timeout=3.0) is not None
        second = _client(server.url)
        with pytest.raises(DeviceUnavailable, match=ANOTHER_CLIENT):
            second.open()
        second.close()
        assert cli.main(["dump", server.url, "--frames", "2"]) == 1  # the device's fault, not the user's
        err = capsys.readouterr().err.strip()
        assert err.startswith("handover dump: ") and ANOTHER_CLIENT in err and "\n" not in err
        for _ in range(20):  # the first host was never kicked off
            assert first.read_frame(timeout=3.0) is not None
        assert server.refused == 2 and server.emulator.stats.connections == 1
        first.close()
    notes = [r.getMessage() for r in caplog.records if r.name == "handover.emulator"]
    assert len(notes) == 1 and notes[0].startswith("refused a connection from 127.0.0.1:"), notes
    assert "another host is connected" in notes[0]


@pytest.fixture
def models(tmp_path):
    (tmp_path / "models").mkdir()
    return write_model(tmp_path / "models", "toy.onnx", tiny_model_bytes()).parent


class _ConnectingClient:
    """A device that connects at once (the logging rule under test is the daemon's, not the link's;
    the real link is the test above)."""

    def __init__(self, url: str) -> None:
        self.url = url

    def open(self, should_stop=None):
        from firmware_io.layout import SensorLayout

        return SensorLayout.sdh2()

    def start(self, should_stop=None) -> None:
        pass

    def close(self, stop_timeout: float | None = None) -> None:
        pass


def test_a_flapping_link_is_logged_rarely_and_health_hears_every_drop(models, caplog):
    clock = ManualClock(1000.0)
    daemon = Daemon(_config(models, "sim://?events=4&realtime=0"), client_factory=_ConnectingClient)
    daemon.link.retry_notes = RetryNotes(clock=clock)
    caplog.set_level(logging.INFO, logger="handover.daemon")
    daemon.link.connect()  # the first connection is said at once
    drops = 2 * 3600 + 300  # every second for two hours and five minutes: up 0.5 s, down 0.5 s
    caplog.clear()
    for _ in range(drops):
        clock.t += 0.5
        daemon.link.fault("the device closed the connection")
        daemon.link.client = None
        clock.t += 0.5
        daemon.link.connect()
        daemon.link.link_held()
    lines = [r.getMessage() for r in caplog.records if r.name == "handover.daemon"]
    assert len(lines) == 5, lines[:8]  # at once, after 1, 10, 60 and 120 minutes
    assert lines[0].startswith("device sim://?events=4&realtime=0: the device closed the connection within "
                               f"{SHORT_LINK_S:g} s of connecting (the device may be serving another client")
    assert "still unreachable after 61 attempts in 60 s" in lines[1]
    assert daemon.health.reconnects == drops and daemon.health.device_faults == drops
    caplog.clear()
    clock.t += SHORT_LINK_S + 0.1
    daemon.link.link_held()  # the link holds: said once
    daemon.link.link_held()
    back = [r.getMessage() for r in caplog.records if r.name == "handover.daemon"]
    assert len(back) == 1 and back[0].startswith(f"device sim://?events=4&realtime=0 reconnected after {drops} failed "
                                                 "attempts in 2.1 h; the link has held"), back
    caplog.clear()
    clock.t += 60
    daemon.link.fault("the device closed the connection")  # a drop after a long link: one line as before
    lines = [r.getMessage() for r in caplog.records if r.name == "handover.daemon"]
    assert lines == ["device sim://?events=4&realtime=0: the device closed the connection; reconnecting"]
    caplog.clear()
    daemon.link.client = None
    daemon.link.connect()
    clock.t += 2.0
    daemon.link.fault("no frame for 2 s (stall)", link_lost=False)  # soon, but a stall: no word of another client
    lines = [r.getMessage() for r in caplog.records if r.name == "handover.daemon"]
    assert lines == ["device sim://?events=4&realtime=0 reconnected (486 taxels, scene model)",
                     "device sim://?events=4&realtime=0: no frame for 2 s (stall) within 5 s of connecting; "
                     f"retrying in 0.2 s{QUIET}"], lines
    daemon.link.close()
