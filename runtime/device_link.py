"""The daemon's link to the device: connect, report faults, reconnect with backoff.

A failing device is retried with doubling backoff, never fatal (logged rarely: runtime.retry_notes);
only a URL that can never work ends the daemon, with one line. The owner hears what happened from
return values; the link calls nothing of its owner but the ``should_stop`` predicate of a slow open.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable
from enum import Enum
from typing import Any, Protocol

from firmware_io.client import Cancelled, DSAClient
from firmware_io.layout import SensorLayout
from firmware_io.transports import DeviceUnavailable, MissingDependency, TransportError, validate_url
from runtime.config import DeviceConfig
from runtime.health import Health, one_line
from runtime.retry_notes import RetryNotes
from runtime.sdnotify import Notifier

__all__ = ["CONNECT_BOUND_S", "SHORT_LINK_S", "DeviceLink", "Linked", "default_client", "log"]

log = logging.getLogger("handover.daemon")

CONNECT_BOUND_S = 30.0
"""Longest one connection attempt may take while the watchdog is still fed: well beyond the
client's own deadlines (``DSAClient.open_timeout`` and, for the start, ``stop_timeout``), so an attempt still
running after this is a hang, and systemd's watchdog is left to catch it."""

SHORT_LINK_S = 5.0
"""A connection the device ends within this long of connecting counts as a failed attempt for the
log (runtime.retry_notes: a link that flaps every second is logged at the 1/10/60 min rate), and
the line that says it is back waits until the link has held this long. The health file still hears
of every drop."""

SHORT_LINK_HINT = (f"within {SHORT_LINK_S:g} s of connecting (the device may be serving another client, "
                   "e.g. a second daemon or handover dump: it serves one host at a time)")
"""Said of a link the device ends soon after connecting; a stall that soon is only said to be that soon."""


class DeviceClient(Protocol):
    """What the link calls on its client (``DSAClient``; tests and replays pass their own). A client may
    also count refusals in a ``stats`` dict and name the last in ``last_refusal``: read where present."""

    def open(self, should_stop: Callable[[], bool]) -> SensorLayout: ...

    def start(self, should_stop: Callable[[], bool]) -> None: ...

    def read_frame(self, timeout: float) -> Any: ...

    def close(self, stop_timeout: float | None = None) -> None: ...


class Linked(Enum):
    """What a connection attempt came to."""

    STREAMING = "streaming"
    """A stream began (``DeviceLink.layout`` is the device's)."""
    RETRY = "retry"
    """Failed (the next attempt scheduled) or cancelled: closed."""
    FATAL = "fatal"
    """The link can never work (``DeviceLink.fatal`` says why)."""


class DeviceLink:
    """Opening, watching and closing the device client (module docstring).

    ``read(timeout)`` is the loop's one call while streaming: a frame, or None (nothing yet, or the
    link failed: then ``connected`` is False, it is closed and a reconnect scheduled). ``connect()``
    when ``due(now)`` says what came of it (``Linked``).
    """

    def __init__(self, device: DeviceConfig, health: Health, notifier: Notifier,
                 client_factory: Callable[[str], DeviceClient] | None = None) -> None:
        self.device = device
        self.health = health
        self.notifier = notifier
        self.client_factory = client_factory or (lambda url: default_client(url, on_wait=self._waiting))
        self._should_stop: Callable[[], bool] = lambda: False
        self.scene = ""
        """The scene's pads, for the log lines (the owner keeps it current)."""
        self.client: DeviceClient | None = None
        self.layout: SensorLayout | None = None
        """The layout of the device the client last opened."""
        self.connected = False
        self.state = "starting"
        """The health view's ``device_state``: starting, connecting, streaming, disconnected, reconnecting,
        stopped or failed."""
        self.faults = 0
        """Streaming links that failed (each one a reconnect)."""
        self.stalls = 0
        """Faults that were a stall (no frame for ``device.stall_timeout_s``)."""
        self._client_counts: dict[str, int] = {}
        """The client's error counts at the last ``update_health`` (cumulative over its reconnects)."""
        self.fatal: str | None = None
        """Why the link can never work (a device URL that can never open, a missing package), or None."""
        self.connect_bound_s = CONNECT_BOUND_S
        self.retry_notes = RetryNotes()
        """Which failed connection attempts get a log line (the first, then after 1, 10, 60 min)."""
        self._backoff = device.reconnect_min_s
        self._next_connect = 0.0
        self._last_frame_t = 0.0
        self._refused_mark = 0
        """Frames the client had refused (CRC, undecodable, implausible) at the last stall."""
        self._connect_started: float | None = None
        self._hang_logged = False
        self._link_up_at: float | None = None
        """When the device connection now up was made (a drop soon after counts as a failed attempt)."""
        self._back_note_due = False
        self._flapping = False

    def due(self, now: float) -> bool:
        """Whether the next connection attempt is due."""
        return now >= self._next_connect

    def wait_s(self, now: float) -> float:
        """Seconds until the next connection attempt."""
        return max(0.0, self._next_connect - now)

    def retarget(self, device: DeviceConfig) -> None:
        """New device settings (a reload); another URL closes the client and connects at once."""
        old, self.device = self.device, device
        if device.url != old.url:
            self.close()
            self.client = None
            self.layout = None
            self._next_connect = 0.0
            self.retry_notes.reset()

    def read(self, timeout: float) -> Any:
        """The next frame, or None after ``timeout`` s; a failed or stalled link is reported, closed and
        scheduled for a reconnect (None)."""
        try:
            frame = self.client.read_frame(timeout)
        except Exception as exc:  # unplug, closed link, end of a replay: reconnect
            self.fault(one_line(exc))
            return None
        now = time.monotonic()
        if frame is None:
            if now - self._last_frame_t > self.device.stall_timeout_s:
                self.stalls += 1
                self.fault(self._stall_reason(), link_lost=False)
            return None
        self._last_frame_t = now
        if not self._flapping:  # a link that keeps dropping soon after connecting keeps backing off
            self._backoff = self.device.reconnect_min_s
        return frame

    def _still_connecting(self) -> bool:
        """The client's cancel predicate while it opens a device (seconds when the device is
        silent): answers SIGTERM within a read slice, keeps the health file current, and feeds
        the watchdog only while the attempt is within ``connect_bound_s`` (a hang past it is
        left to systemd's watchdog)."""
        now = time.monotonic()
        started = self._connect_started
        if started is None or now - started < self.connect_bound_s:
            self.notifier.watchdog(now)
        elif not self._hang_logged:
            self._hang_logged = True
            self.health.report_error(f"{self.device.url}: connecting has not completed in "
                                     f"{self.connect_bound_s:g} s", "device")
            log.error("device %s: connecting has not completed in %g s; no longer feeding the watchdog "
                      "(systemd restarts the service)", self.device.url, self.connect_bound_s)
        return self._should_stop()

    def _waiting(self, line: str) -> None:
        """The client's line when an open waits for a silent controller (a boot: seconds with no log line
        look hung); said on the first attempt of an outage only, the later ones are the retry notes'."""
        if self.retry_notes.attempts == 0:
            log.info("device %s", line)

    def connect(self, should_stop: Callable[[], bool] = lambda: False) -> Linked:
        """One attempt to open the device; ``should_stop()`` is asked between reads of a slow open (True
        cancels it)."""
        self._should_stop = should_stop
        h = self.health
        url = self.device.url
        self._connect_started, self._hang_logged = time.monotonic(), False
        if self.state in ("starting", "stopped"):
            self.state = "connecting"
        try:
            if self.client is None:
                self._use_new_client(url)
            layout = self.client.open(should_stop=self._still_connecting)
            self.client.start(should_stop=self._still_connecting)
        except Cancelled:
            self._connect_started = None
            self.close()
            return Linked.RETRY
        except Exception as exc:  # unplugged, refused, wrong device: report and retry, never die
            self._connect_failed(url, exc)
            return Linked.FATAL if self.fatal else Linked.RETRY
        self._connect_started = None
        self.connected = True
        first = self.layout is None
        self.layout = layout
        self._last_frame_t = time.monotonic()
        self.state = "streaming"
        h.resolve("device")
        self._link_up_at = self.retry_notes.clock()
        self._back_note_due = self.retry_notes.attempts > 0 and self._flapping
        if not self._back_note_due:  # after short links, said once this link holds (link_held)
            log.info("device %s %s%s (%d taxels, scene %s)", url, "connected" if first else "reconnected",
                     self.retry_notes.connected(), layout.n_taxels, self.scene)
            self._flapping = False
        return Linked.STREAMING

    def link_held(self) -> None:
        """After an outage of short links: the line that says the device is back, once the link has
        held ``SHORT_LINK_S`` (called from the loop's housekeeping)."""
        if self._back_note_due and self.connected and self._link_up_at is not None \
                and self.retry_notes.clock() - self._link_up_at >= SHORT_LINK_S:
            self._back_note_due = self._flapping = False
            n_taxels = self.layout.n_taxels if self.layout is not None else 0
            log.info("device %s reconnected%s; the link has held %g s (%d taxels, scene %s)", self.device.url,
                     self.retry_notes.connected(), SHORT_LINK_S, n_taxels, self.scene)

    def _connect_failed(self, url: str, exc: Exception) -> None:
        fatal = fatal_device_error(url, exc)
        if fatal:
            self.fatal = fatal  # the owner stops; run() returns 2 and the caller prints it (one line)
            self.close()
            return
        self._connect_started = None
        self.state = "disconnected"
        reason = one_line(exc).removeprefix(f"{url}: ")
        self.health.report_error(f"{url}: {reason}", "device")  # every attempt: the health file stays current
        self._note_failed_attempt(url, reason)
        self._schedule_reconnect()
        self.close()

    def _note_failed_attempt(self, url: str, reason: str) -> None:
        """A failed attempt for the retry log: a line only when something is new (runtime.retry_notes)."""
        note = self.retry_notes.failed(reason, self._backoff)
        if note:
            log.warning("device %s: %s", url, note)

    def _schedule_reconnect(self) -> None:
        self._next_connect = time.monotonic() + self._backoff
        self._backoff = min(self.device.reconnect_max_s, max(self._backoff * 2, 0.05))

    def fault(self, reason: str, link_lost: bool = True) -> None:
        """The link failed while streaming (``link_lost``: closed or lost, else a stall): counted, reconnected."""
        url = self.device.url
        reason = reason.removeprefix(f"{url}: ")
        self.faults += 1
        self.state = "reconnecting"
        self.health.report_error(f"{url}: {reason}", "device")  # every drop: the health file stays current
        up = self._link_up_at
        self._link_up_at = None
        if up is not None and self.retry_notes.clock() - up < SHORT_LINK_S:  # a flapping link: logged as a failed attempt
            self._flapping = True
            soon = SHORT_LINK_HINT if link_lost else f"within {SHORT_LINK_S:g} s of connecting"
            self._note_failed_attempt(url, f"{reason} {soon}")
        else:
            log.warning("device %s: %s; reconnecting", url, reason)
        self.close()
        self._schedule_reconnect()

    def close(self, stop_timeout: float | None = None) -> None:
        self.connected = False
        if self.client is not None:
            with contextlib.suppress(Exception):
                self.client.close(stop_timeout=stop_timeout)

    def _use_new_client(self, url: str) -> None:
        """A new client counts its refusals from 0 (the mark was the old one's)."""
        self.client = self.client_factory(url)
        self._refused_mark = 0

    def _refusals(self) -> int:
        stats = getattr(self.client, "stats", None)
        return sum(int(stats.get(k, 0)) for k in REFUSALS) if isinstance(stats, dict) else 0

    def update_health(self, now: float, period_s: float) -> None:
        """Called every ``period_s`` (the health write): the client's error counters (cumulative over
        reconnects of the same client); and, while usable frames still arrive, the refusals so far are
        not a coming stall's (a device alternating good and refused frames, then silent, read as one
        whose every frame was refused)."""
        stats = getattr(self.client, "stats", None)
        if isinstance(stats, dict):
            self._client_counts = {
                "crc_errors": int(stats.get("crc_errors", 0)),
                "protocol_errors": int(stats.get("bad_headers", 0)) + int(stats.get("decode_errors", 0)),
                "frames_implausible": int(stats.get("frames_implausible", 0)),
                "frames_stale": int(stats.get("frames_stale", 0))}
        if self.connected and now - self._last_frame_t <= period_s:
            self._refused_mark = self._refusals()

    def counters(self) -> dict[str, int | str]:
        return {"device_state": self.state, "reconnects": self.faults, "device_faults": self.faults,
                "stalls": self.stalls, **self._client_counts}

    def shutdown(self, stop_timeout: float) -> None:
        """The daemon stops: the device closed, the state ``stopped`` (``failed`` when the link can never work)."""
        self.close(stop_timeout=stop_timeout)
        self.state = "failed" if self.fatal else "stopped"

    def _stall_reason(self) -> str:
        """The stall's line. Frames that arrived whole but were all refused (CRC, undecodable,
        implausible) are named with the last reason: a device sending nonsense is not a silent one."""
        stall_s = self.device.stall_timeout_s
        refused = self._refusals()
        new = refused - self._refused_mark if refused >= self._refused_mark else refused
        self._refused_mark = refused
        if new <= 0:
            return f"no frame for {stall_s:g} s (stall)"
        last = getattr(self.client, "last_refusal", None)
        return (f"no usable frame for {stall_s:g} s: {new} arrived but were refused (CRC, undecodable or "
                f"implausible{'; last: ' + last if last else ''}); check the cable and that the device is a "
                "DSACON32m with the hand's pads")


REFUSALS = ("crc_errors", "decode_errors", "frames_implausible")
"""The client's counts of frames that arrived whole but were not used."""


def default_client(url: str, on_wait: Callable[[str], None] | None = None) -> DeviceClient:
    # The daemon reconnects itself (with backoff, answering SIGTERM and the watchdog meanwhile).
    return DSAClient(url, auto_reconnect=False, on_wait=on_wait)


def fatal_device_error(url: str, exc: BaseException) -> str | None:
    """A device error no retry can cure: the URL itself is wrong, or a package is missing.

    Everything else (unplugged, refused, silent, wrong replies) is retried with backoff."""

    if not isinstance(exc, TransportError) or isinstance(exc, DeviceUnavailable):
        return None
    if isinstance(exc, MissingDependency):
        return f"device.url: {one_line(exc)}"
    try:
        validate_url(url)
    except TransportError as bad:
        return f"device.url: {one_line(bad)}"
    return None  # e.g. a write timeout: a device condition, retried
