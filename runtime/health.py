"""Health view: counters, latency median/p99 over a sliding window, a JSON status file at ~1 Hz.

The same numbers make the systemd STATUS line. Recording a latency is one store into a
preallocated array; percentiles are computed only when the status is written.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import time
from collections import deque
from pathlib import Path

import numpy as np

__all__ = ["Health", "StatusFile", "log", "one_line", "write_json_atomically"]

log = logging.getLogger("handover.health")
ERROR_HISTORY = 8

FRAME_ERROR_LOG_S = 10.0
"""At most one log line this often for exceptions while handling frames (all are counted)."""


class Health:
    """All counters the daemon reports."""

    def __init__(self, latency_window: int = 2048) -> None:
        self.started = time.time()
        self.frames_received = 0
        self.frames_dropped = 0
        """Frames the device sent but we never saw (gaps in device time)."""
        self.frames_stale = 0
        """Frames received but discarded because the loop fell behind (client queue overflow)."""
        self.frames_decimated = 0
        """Frames of a stream faster than the model's rate left out to feed it at its period (runtime/frame_rate.py)."""
        self.crc_errors = 0
        self.protocol_errors = 0
        self.reconnects = 0
        self.device_faults = 0
        self.stalls = 0
        """Device faults that were a stall (no frame for ``device.stall_timeout_s``)."""
        self.decisions = 0
        self.events = 0
        self.missed_deadlines = 0
        self.sink_errors = 0
        self.models_loaded = 0
        self.models_rejected = 0
        self.models_quarantined = 0
        """Models taken out of service at run time (a label out of range, NaN scores, a failed run)."""
        self.frames_implausible = 0
        """Frames the sensor cannot have sent (above 12 bits, pressure on a cell that does not exist):
        dropped by the client, never classified."""
        self.frame_errors = 0
        """Exceptions while handling a frame (the loop went on)."""
        self.events_invalid = 0
        """Events not sent because they were not valid JSON (NaN/inf)."""
        self.arm_moving = False
        """The robot's last word on its arm (runtime.arm_motion)."""
        self.arm_windows = 0
        """Windows judged dormant because the arm moved during them (the model did not run)."""
        self.control_ignored = 0
        """Control datagrams that were not a known message, or from a sender not heard (counted, logged once)."""
        self.model_id: str | None = None
        self.instance = ""
        """Which daemon this is (runtime.instance_name), as in its event lines."""
        self.trigger: str | None = None
        """The trigger serving now, with its settings (e.g. ``onset (change 0.12, ...)``), or None without a model."""
        self.device_state = "starting"
        self.last_error = ""
        """The problem that holds now ("" once it is resolved: streaming again, a model serving)."""
        self.last_error_at: float | None = None
        self.errors: deque[dict] = deque(maxlen=ERROR_HISTORY)
        """The last few problems with their time, including resolved ones."""
        self._error_source = ""
        self._held: dict[str, str | None] = {}
        self._last_frame_error_log = -FRAME_ERROR_LOG_S
        self._lat = np.zeros(latency_window, dtype=np.float64)
        self._lat_n = 0
        self.latency_max_us = 0.0
        self._rate_t = time.monotonic()
        self._rate_frames = 0
        self.frame_rate = 0.0

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

    def record_latency(self, latency_us: float) -> None:
        self._lat[self._lat_n % self._lat.size] = latency_us
        self._lat_n += 1
        if latency_us > self.latency_max_us:
            self.latency_max_us = latency_us

    def latency_percentiles(self) -> tuple[float | None, float | None]:
        n = min(self._lat_n, self._lat.size)
        if n == 0:
            return None, None
        p50, p99 = np.percentile(self._lat[:n], [50, 99])
        return float(p50), float(p99)

    def update_rate(self, now: float | None = None) -> None:
        now = time.monotonic() if now is None else now
        dt = now - self._rate_t
        if dt >= 1.0:
            # the device's rate: frames it sent that the client dropped as implausible count too, else dropped
            # frames would make the device look slower and the rate check blame the stream
            sent = self.frames_received + self.frames_implausible
            self.frame_rate = max(0, sent - self._rate_frames) / dt
            self._rate_t, self._rate_frames = now, sent

    def snapshot(self) -> dict:
        p50, p99 = self.latency_percentiles()
        return {
            "time": time.time(),
            "instance": self.instance,
            "uptime_s": round(time.time() - self.started, 3),
            "device_state": self.device_state,
            "frame_rate_hz": round(self.frame_rate, 2),
            "frames_received": self.frames_received,
            "frames_dropped": self.frames_dropped,
            "frames_stale": self.frames_stale,
            "frames_decimated": self.frames_decimated,
            "crc_errors": self.crc_errors,
            "protocol_errors": self.protocol_errors,
            "reconnects": self.reconnects,
            "device_faults": self.device_faults,
            "stalls": self.stalls,
            "decisions": self.decisions,
            "events": self.events,
            "missed_deadlines": self.missed_deadlines,
            "latency_p50_us": None if p50 is None else round(p50, 1),
            "latency_p99_us": None if p99 is None else round(p99, 1),
            "latency_max_us": round(self.latency_max_us, 1),
            "sink_errors": self.sink_errors,
            "models_loaded": self.models_loaded,
            "models_rejected": self.models_rejected,
            "models_quarantined": self.models_quarantined,
            "frames_implausible": self.frames_implausible,
            "frame_errors": self.frame_errors,
            "events_invalid": self.events_invalid,
            "arm_moving": self.arm_moving,
            "arm_windows": self.arm_windows,
            "control_ignored": self.control_ignored,
            "model_id": self.model_id,
            "trigger": self.trigger,
            "last_error": self.last_error,
            "last_error_at": None if self.last_error_at is None else round(self.last_error_at, 3),
            "recent_errors": list(self.errors),
        }

    def status_line(self) -> str:
        """One line for ``systemctl status``: rates, latency, model in use."""
        p50, p99 = self.latency_percentiles()
        lat = "latency -" if p50 is None else f"latency p50 {p50:.0f}us p99 {p99:.0f}us"
        return (
            f"{self.device_state}; {self.frame_rate:.1f} frames/s; {self.events} events; {lat}; "
            f"missed {self.missed_deadlines}; dropped {self.frames_dropped}; crc {self.crc_errors}; "
            f"model {self.model_id or 'none'}"
        )


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


def one_line(exc: BaseException) -> str:
    """The first line of an exception's text (its type name if empty): how errors reach the health
    file and the log, one line each."""
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__
