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
