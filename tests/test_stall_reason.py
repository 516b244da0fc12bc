"""The stall line counts the refused frames of the stall itself: not those refused while good frames
still flowed before it, and a client replaced on reconnect counts its own from 0."""

from __future__ import annotations

import time

from runtime.config import DeviceConfig
from runtime.device_link import DeviceLink
from runtime.health import Health
from runtime.sdnotify import Notifier


class Client:
    def __init__(self) -> None:
        self.stats = {"crc_errors": 0, "decode_errors": 0, "frames_implausible": 0}
        self.last_refusal = "CRC mismatch"


def _link(client: Client) -> DeviceLink:
    link = DeviceLink(DeviceConfig(stall_timeout_s=2.0), Health(), Notifier({}), client_factory=lambda url: client)
    link._use_new_client("x://")
    link.connected = True
    link._last_frame_t = time.monotonic()
    return link


def test_refusals_among_good_frames_are_not_the_silent_stall_s():
    """Good and refused frames alternating for a minute, then silence: the stall said `60 arrived but
    were refused` of a device that had simply gone quiet."""
    client = Client()
    link = _link(client)
    for _ in range(60):  # a good frame, a refused one; the daemon's periodic health write in between
        link._last_frame_t = time.monotonic()
        client.stats["crc_errors"] += 1
        link.update_health(time.monotonic(), 1.0)
    assert link._stall_reason() == "no frame for 2 s (stall)"
    client.stats["crc_errors"] += 7  # now only refused frames arrive: the next stall names them
    assert "7 arrived but were refused" in link._stall_reason()


def test_a_client_replaced_on_reconnect_counts_from_zero():
    old = Client()
    link = _link(old)
    old.stats["crc_errors"] = 5
    assert "5 arrived" in link._stall_reason()
    new = Client()
    link.client_factory = lambda url: new
    link.client = None
    link._use_new_client("x://")
    new.stats["decode_errors"] = 5  # as many as the old one had: all of them this stall's
    assert "5 arrived" in link._stall_reason()


def test_a_connection_attempt_says_what_came_of_it_and_calls_nothing_of_its_owner():
    """The link took four callbacks from the daemon (a new stream, housekeeping while connecting, stop,
    a fault); now ``connect`` returns what happened and a fault leaves ``connected`` False."""
    import inspect

    from firmware_io.client import Cancelled
    from firmware_io.transports import DeviceUnavailable, TransportError
    from runtime.device_link import Linked

    assert list(inspect.signature(DeviceLink).parameters) == ["device", "health", "notifier", "client_factory"]

    class Opening(Client):
        def __init__(self, opens) -> None:
            super().__init__()
            self.opens = opens

        def open(self, should_stop):
            should_stop()
            return self.opens()

        def start(self, should_stop) -> None:
            pass

        def read_frame(self, timeout):
            raise OSError("unplugged")

        def close(self, **_) -> None:
            pass

    from types import SimpleNamespace

    layout = SimpleNamespace(n_taxels=486)
    link = DeviceLink(DeviceConfig(), Health(), Notifier({}), client_factory=lambda url: Opening(lambda: layout))
    asked = []
    assert link.connect(lambda: asked.append(1) or False) is Linked.STREAMING and link.layout is layout and asked
    assert link.read(0.01) is None and not link.connected  # a fault: closed, reconnect scheduled

    def unplugged():
        raise DeviceUnavailable("x: no such device")

    def cancelled():
        raise Cancelled()

    for opens, came in ((unplugged, Linked.RETRY), (cancelled, Linked.RETRY)):
        link = DeviceLink(DeviceConfig(), Health(), Notifier({}), client_factory=lambda url, o=opens: Opening(o))
        assert link.connect() is came and not link.connected
    def bad_url():
        raise TransportError("bad scheme")

    bad = DeviceLink(DeviceConfig(url="nowhere://x"), Health(), Notifier({}), client_factory=lambda url: Opening(bad_url))
    assert bad.connect() is Linked.FATAL and bad.fatal


def test_every_call_the_link_makes_on_its_client_is_declared_in_its_protocol():
    import inspect
    import re

    import runtime.device_link as module
    from runtime.device_link import DeviceClient

    called = set(re.findall(r"self\.client\.(\w+)\(", inspect.getsource(module)))
    assert called and called <= {name for name in vars(DeviceClient) if not name.startswith("_")}, called


def test_the_daemon_logs_the_clients_wait_for_a_silent_controller_on_an_outages_first_attempt_only(monkeypatch, caplog):
    """Between "ready" and "connected" a booting controller kept the log silent for 8 s; the client's
    line says what the open waits for. Later attempts of the same outage are the retry notes' (rare)."""
    import logging

    import runtime.device_link as module
    from firmware_io.client import DSATimeout

    class Booting:
        def __init__(self, url, auto_reconnect, on_wait) -> None:
            self.url, self.on_wait = url, on_wait

        def open(self, should_stop):
            self.on_wait(f"{self.url}: no answer yet; waiting up to 9 s for the controller to answer ...")
            raise DSATimeout(f"{self.url}: open did not complete within 10 s")

        def close(self, **_) -> None:
            pass

    monkeypatch.setattr(module, "DSAClient", Booting)
    link = DeviceLink(DeviceConfig(url="tcp://10.0.0.9:13000"), Health(), Notifier({}))
    with caplog.at_level(logging.INFO, logger="handover.daemon"):
        link.connect()
        link.connect()
    said = [r.getMessage() for r in caplog.records if "waiting" in r.getMessage()]
    assert said == ["device tcp://10.0.0.9:13000: no answer yet; waiting up to 9 s for the controller to answer ..."]
