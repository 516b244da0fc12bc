"""Health view: the counters each part of the daemon keeps, composed; latency median/p99 over a
sliding window; a JSON status file at ~1 Hz. The same numbers make the systemd STATUS line.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import stat
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["Health", "Latency", "StatusFile", "log", "one_line", "write_json_atomically",
           "write_problem"]

log = logging.getLogger("handover.health")
ERROR_HISTORY = 8

FRAME_ERROR_LOG_S = 10.0
"""At most one log line this often for exceptions while handling frames (all are counted)."""


SNAPSHOT: dict[str, Any] = {
    "time": None, "instance": "", "uptime_s": 0.0, "device_state": "starting", "frame_rate_hz": 0.0,
    "frames_received": 0, "frames_dropped": 0, "frames_stale": 0, "frames_decimated": 0, "crc_errors": 0,
    "protocol_errors": 0, "reconnects": 0, "device_faults": 0, "stalls": 0, "decisions": 0, "events": 0,
    "missed_deadlines": 0, "latency_p50_us": None, "latency_p99_us": None, "latency_max_us": 0.0, "sink_errors": 0,
    "models_loaded": 0, "models_rejected": 0, "models_quarantined": 0, "frames_implausible": 0, "frame_errors": 0,
    "events_invalid": 0, "arm_moving": False, "arm_windows": 0, "control_ignored": 0, "capture_events": 0, "capture_idle": 0,
    "capture_outcomes": 0, "capture_outcomes_refused": 0, "capture_dropped": 0, "capture_errors": 0, "capture_bytes": 0,
    "model_id": None, "trigger": None, "shadow": None, "last_error": "", "last_error_at": None, "recent_errors": [],
}
"""The health file's keys in order, each with its value before its part reports."""


class Health:
    """The health view: the problem log (``report_error``, ``resolve``, ``hold``) and a snapshot composed of
    the counters each part keeps and reports itself (``parts``: the daemon's link, detector, model slot,
    reporter and its own). Why: one writer per counter; a counter is read here as ``health.<key>``."""

    def __init__(self) -> None:
        self.started = time.time()
        self.parts: list[Callable[[], dict[str, Any]]] = []
        self.frame_errors = 0
        """Exceptions while handling a frame (the loop went on)."""
        self.instance = ""
        """Which daemon this is (runtime.instance_name), as in its event lines."""
        self.last_error = ""
        """The problem that holds now ("" once it is resolved: streaming again, a model serving)."""
        self.last_error_at: float | None = None
        self.errors: deque[dict] = deque(maxlen=ERROR_HISTORY)
        """The last few problems with their time, including resolved ones."""
        self._error_source = ""
        self._held: dict[str, str | None] = {}
        self._last_frame_error_log = -FRAME_ERROR_LOG_S
        self._rate_t = time.monotonic()
        self._rate_frames = 0
        self.frame_rate = 0.0

    def counters(self) -> dict[str, Any]:
        """Every part's counters now, merged."""
        merged: dict[str, Any] = {"frame_errors": self.frame_errors}
        for part in self.parts:
            merged.update(part())
        return merged

    def __getattr__(self, name: str) -> Any:
        """A part's counter by its health key (``health.events``); read-only."""
        if name.startswith("_") or name == "parts":
            raise AttributeError(name)
        counters = self.counters()
        if name in counters or name in SNAPSHOT:
            return counters.get(name, SNAPSHOT[name])
        raise AttributeError(name)

    def report_error(self, text: str, source: str) -> None:
        """A problem from ``source`` (``device``, ``model``, ``config``, ``quarantine``, ``frame``) that
        holds until ``resolve(source)`` (a quarantine stays: another model serving does not undo it)."""
        now = time.time()
        self.last_error, self.last_error_at, self._error_source = text, now, source
        newest = self.errors[-1] if self.errors else None
        if newest is not None and newest["source"] == source and newest["error"] == text:
            # a repeat (a device refusing every retry) is counted, not appended: the history keeps
            # the problems before a long outage
            newest["repeats"] = newest.get("repeats", 1) + 1
            newest["last_at"] = round(now, 3)
            return
        self.errors.append({"at": round(now, 3), "source": source, "error": text})

    def hold(self, source: str, text: str | None) -> None:
        """``text`` is ``source``'s problem now, or None: reported or resolved only when it changes."""
        if text and text != self._held.get(source):
            self.report_error(text, source)
        elif not text and self._held.get(source):
            self.resolve(source)
        self._held[source] = text

    def resolve(self, source: str) -> None:
        """``source`` works again: its error stops being the current one (it stays in ``errors``)."""
        if self._error_source == source:
            self.last_error, self._error_source = "", ""

    def frame_failed(self, message: str, now: float | None = None) -> bool:
        """Count an exception while handling a frame; True when a log line is due (rate limit)."""
        self.frame_errors += 1
        now = time.monotonic() if now is None else now
        if now - self._last_frame_error_log < FRAME_ERROR_LOG_S:
            self.last_error = f"frame handling failed: {message}"
            return False
        self._last_frame_error_log = now
        self.report_error(f"frame handling failed: {message}", "frame")  # in the history once per log line
        return True

    def update_rate(self, now: float | None = None) -> None:
        now = time.monotonic() if now is None else now
        dt = now - self._rate_t
        if dt >= 1.0:
            # the device's rate: frames it sent that the client dropped as implausible count too (30 % of frames
            # above 4095 made the device look 30 % slower, and the rate check blame the stream)
            counters = self.counters()
            sent = counters.get("frames_received", 0) + counters.get("frames_implausible", 0)
            self.frame_rate = max(0, sent - self._rate_frames) / dt
            self._rate_t, self._rate_frames = now, sent

    def snapshot(self) -> dict:
        now = time.time()
        data = {**self.counters(), "time": now, "instance": self.instance, "uptime_s": round(now - self.started, 3),
                "frame_rate_hz": round(self.frame_rate, 2), "last_error": self.last_error,
                "last_error_at": None if self.last_error_at is None else round(self.last_error_at, 3),
                "recent_errors": list(self.errors)}
        return {key: data.get(key, default) for key, default in SNAPSHOT.items()}

    def status_line(self, snapshot: dict | None = None) -> str:
        """One line for ``systemctl status``: rates, latency, model in use."""
        h = snapshot or self.snapshot()
        p50, p99 = h["latency_p50_us"], h["latency_p99_us"]
        lat = "latency -" if p50 is None else f"latency p50 {p50:.0f}us p99 {p99:.0f}us"
        return (
            f"{h['device_state']}; {h['frame_rate_hz']:.1f} frames/s; {h['events']} events; {lat}; "
            f"missed {h['missed_deadlines']}; dropped {h['frames_dropped']}; crc {h['crc_errors']}; "
            f"model {h['model_id'] or 'none'}"
        )


class Latency:
    """Decision latencies over a sliding window: recording one is one store into a preallocated array;
    the percentiles are computed only when the health view is written."""

    def __init__(self, window: int = 2048) -> None:
        self._lat = np.zeros(window, dtype=np.float64)
        self._n = 0
        self.max_us = 0.0

    def record(self, latency_us: float) -> None:
        self._lat[self._n % self._lat.size] = latency_us
        self._n += 1
        if latency_us > self.max_us:
            self.max_us = latency_us

    def counters(self) -> dict[str, float | None]:
        n = min(self._n, self._lat.size)
        p50, p99 = np.percentile(self._lat[:n], [50, 99]) if n else (None, None)
        return {"latency_p50_us": None if p50 is None else round(float(p50), 1),
                "latency_p99_us": None if p99 is None else round(float(p99), 1), "latency_max_us": round(self.max_us, 1)}


class StatusFile:
    """The JSON status file, written atomically; an unwritable file never floods the log.

    The first failure is logged, then at most one line every ``log_every_s`` seconds with the
    number of failures since, and one line when writing works again.
    """

    def __init__(self, path: str | Path, log_every_s: float = 300.0) -> None:
        self.path = Path(path)
        self.log_every_s = float(log_every_s)
        self.failures = 0
        """Failed writes in total."""
        self._unlogged = 0
        self._last_log: float | None = None
        self._failing = False

    def write(self, data: dict, now: float | None = None) -> bool:
        """True when written; False (and maybe one log line) when not."""
        try:
            write_json_atomically(self.path, data)
        except (OSError, ValueError) as exc:  # ValueError: a path with no file name
            self.failures += 1
            self._unlogged += 1
            self._failing = True
            now = time.monotonic() if now is None else now
            if self._last_log is None or now - self._last_log >= self.log_every_s:
                more = f" ({self._unlogged} failed writes since the last message)" if self._last_log is not None else ""
                log.warning("health file %s: %s%s", self.path, getattr(exc, "strerror", None) or exc, more)
                self._last_log, self._unlogged = now, 0
            return False
        if self._failing:
            log.info("health file %s: written again (%d failed writes in total)", self.path, self.failures)
            self._failing, self._last_log, self._unlogged = False, None, 0
        return True


def write_json_atomically(p: Path, data: dict) -> None:
    """JSON to a temp file in the same folder, then renamed over ``p``; OSError passes on (temp removed)."""
    tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp")
    try:
        tmp.write_text(json.dumps(data, indent=1) + "\n")
        os.replace(tmp, p)
    except OSError:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        raise


def write_problem(path: str | os.PathLike) -> str | None:
    """Why this process could not write the health file at ``path``, or None. It is replaced by a temp
    file renamed in its folder (``write_json_atomically``), so the folder must be writable (a lock file
    there that is, or the file itself, proves nothing); in a sticky folder the file, if there, must be ours."""
    p, uid = Path(path), os.geteuid()
    if not os.access(p.parent, os.W_OK | os.X_OK, effective_ids=os.access in os.supports_effective_ids):
        return (f"health_file {p}: its folder {p.parent} is not writable for uid {uid} (the file is replaced by a new "
                "one there); make the folder writable for the daemon's user or choose another path")
    with contextlib.suppress(OSError):
        if os.stat(p.parent).st_mode & stat.S_ISVTX and uid not in (0, owner := os.lstat(p).st_uid):
            return (f"health_file {p}: belongs to uid {owner} in a sticky folder, so uid {uid} cannot "
                    "replace it; remove it or choose another path")
    return None


def one_line(exc: BaseException) -> str:
    """The first line of an exception's text (its type name if empty): how errors reach the health
    file and the log, one line each."""
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__
