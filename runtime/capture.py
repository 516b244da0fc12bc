"""Field capture on the hot path: every decided window with its context, a sample of idle, the robot's outcome.

A ``FrameListener`` (runtime.listeners) copies each frame into its own preallocated ring (one row write, no
allocation). A decided window is kept from ``PRE_FRAMES`` before its first frame to ``POST_FRAMES`` after
the frame it was decided on: once those frames are in, one copy goes to the writer thread
(runtime.capture_writer), which alone touches the disk. Why those margins: a trial must start on the
settled grasp, as ``handover train`` cuts cases (its onset trigger is told the grasp settled at a trial's
first frame; the trigger's baseline settles within ``trigger.track_tau_s`` = 1 s), and what the object
did after the decision (taken, still held) is what a reviewer looks at. In trigger mode a window decided
dormant (or as a class not reported) is kept too (``kind`` "unreported"): a person may correct it in
review, and it is the dormant data the daemon's own trigger finds; continuous mode keeps reports only.

Idle: at most one stretch of ``IDLE_S`` seconds of device time per ``[capture] idle_every_s``, taken
when no window was decided during it, none is open at its end, and the robot's arm and grasp words stayed
the same: source ``arm_move`` while the arm moves, ``open`` when the grasp is open, else ``quiet``
(firmware_io.recordings.idle_stretches' names, so ``handover train`` reads it as dormant data of that kind).
"""

from __future__ import annotations

import logging
import time
from collections import deque
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from firmware_io.recordings.field_capture import META_KEY, event_name, idle_name, outcome_problem
from runtime.capture_writer import Capture, CaptureWriter, Outcome
from runtime.listeners import FrameListener

if TYPE_CHECKING:
    from runtime.detector import Decision, Detector

__all__ = ["IDLE_S", "POST_FRAMES", "PRE_FRAMES", "FieldCapture"]

log = logging.getLogger("handover.capture")

PRE_FRAMES = 32
"""Frames kept before a window's first frame: 1 s at 32 Hz (module docstring)."""
POST_FRAMES = 32
"""Frames kept after the frame a window was decided on: 1 s at 32 Hz."""
IDLE_S = 10.0
"""One idle stretch's length in device seconds (the recorder's stretches are 5-20 s)."""
RING_FRAMES = 512
"""Frames the ring holds (16 s at 32 Hz): an idle stretch and an event's margins fit with room to spare."""
PENDING = 8
"""Decided windows waiting for their post-report frames at most (continuous mode reports at most a few)."""
REFUSED_LOG_S = 10.0
"""At most one log line per this many seconds for each kind of refused outcome (all are counted)."""
OUTCOMES_PER_EVENT = 4
"""Outcomes kept per event at most (a word, then a person's correction or two): a robot repeating its word
at 1 kHz filled a 1 MB folder with outcomes.jsonl in 6 s, and max_mb then removed every captured event."""
SUBJECT = "field"
"""The subject of every captured recording (the trial's and the idle's): the working day, not a person."""


@dataclass
class _Pending:
    stem: str
    start: int
    report: int
    end: int
    meta: dict
    trial: dict


class FieldCapture(FrameListener):
    """The hot thread's half of field capture (module docstring); ``outcome`` is called from other threads."""

    def __init__(self, writer: CaptureWriter, detector: Detector, instance: str = "", idle_every_s: float = 600.0,
                 capacity: int = RING_FRAMES) -> None:
        self.writer, self.detector, self.instance = writer, detector, instance
        self.idle_every_ms = 1000.0 * idle_every_s
        self.capacity = capacity
        self._frames = np.zeros((0, 0), np.uint16)
        self._stamps = np.zeros(capacity, np.float64)
        """Device time of each row, ms."""
        self._numbers = np.zeros(capacity, np.int64)
        self._pos = self._count = 0
        self._pending: deque[_Pending] = deque()
        self.last_event: str | None = None
        """The stem of the newest reported event: the robot's next outcome is about it."""
        self.refused = 0
        """Outcomes refused (an unknown word, no event to attach to, over ``OUTCOMES_PER_EVENT``)."""
        self._refused_logged: dict[str, float] = {}
        """When a refusal of each kind (no event yet, an unknown word, too many) was last logged."""
        self._said: tuple[str | None, int] = (None, 0)
        """The event outcomes were last kept for, and how many."""
        self._idle_start: float | None = None
        """Device ms since which no window was decided and the robot's words stayed the same (None: not idle)."""
        self._idle_state: tuple = ()
        self.failures = 0
        """Exceptions inside capture on the hot thread (a bug): the frame and its decision go on without it."""
        self._failure_logged = float("-inf")
        self._next_idle = float("-inf")

    def counters(self) -> dict[str, int]:
        counts = self.writer.counters()
        counts["capture_errors"] += self.failures
        return {**counts, "capture_outcomes_refused": self.refused}

    # -- the hot thread -----------------------------------------------------------------------
    def on_frame(self, frame: Any) -> None:
        """The frame into the ring (before the detector sees it: a failure here must never cost its decision)."""
        try:
            self._on_frame(frame)
        except Exception as exc:
            self._failed(exc)

    def on_decision(self, decision: Decision) -> None:
        try:
            self._on_decision(decision)
        except Exception as exc:
            self._failed(exc)

    def _failed(self, exc: Exception) -> None:
        """A bug of capture's own: counted as a capture error, logged at most every ``REFUSED_LOG_S``."""
        self.writer.full += 1
        self.failures += 1
        now = time.monotonic()
        if now - self._failure_logged >= REFUSED_LOG_S:
            self._failure_logged = now
            log.error("capture: %s: %s (%d so far; detection goes on)", type(exc).__name__, exc, self.failures)

    def _on_frame(self, frame: Any) -> None:
        values, t = frame.values, float(frame.timestamp_ms)
        if self._frames.shape[1] != values.shape[0]:
            self._frames = np.zeros((self.capacity, values.shape[0]), np.uint16)
            self._restart()
        elif self._count and t <= self._stamps[self._pos - 1]:  # a new stream: its device time starts afresh
            self._restart()
        row = self._pos
        self._frames[row] = values
        self._stamps[row] = t
        self._numbers[row] = frame.number
        self._pos = row + 1 if row + 1 < self.capacity else 0
        self._count += 1
        while self._pending and frame.number >= self._pending[0].end:
            self._send(self._pending.popleft())
        if self.idle_every_ms > 0:
            self._idle(t)

    def _on_decision(self, decision: Decision) -> None:
        det = self.detector
        reported = decision.report >= 0
        if not reported and det.windows.every_frame:  # continuous mode: a decision every frame, reports only
            return
        self._idle_start = None
        frame, model = decision.frame, decision.model
        classes = model.meta.classes
        now = time.time()
        stem = event_name(frame.number, now)
        cls = classes[decision.report if reported else decision.label]
        settings = det.trigger_settings
        meta = {"kind": "event" if reported else "unreported", "class": cls,
                "scores": {c: round(float(s), 6) for c, s in zip(classes, decision.scores[0].tolist(), strict=True)},
                "model_id": model.model_id, "instance": self.instance, "frame_first": int(decision.first),
                "frame_last": int(frame.number), "report_frame": None, "device_time_ms": int(frame.timestamp_ms),
                "time": now, "trigger": None if det.windows.every_frame or settings is None else asdict(settings),
                "arm_moving": bool(det.arm.moving), "grasp_closed": det.grasp_closed}
        if len(self._pending) >= PENDING:
            self.writer.full += 1
        else:
            self._pending.append(_Pending(stem, decision.first - PRE_FRAMES, frame.number, frame.number + POST_FRAMES,
                                          meta, {"subject": SUBJECT, "object": "-", "pose": "-", "action": cls, "run": 0}))
        if reported:
            self.last_event = stem

    def close(self) -> None:
        """Between frames, at the end: windows waiting for post-report frames are kept with what they have,
        and the writer writes what it holds, then ends."""
        while self._pending:
            self._send(self._pending.popleft())
        self.writer.stop()

    def _restart(self) -> None:
        """The ring forgets its frames; windows waiting for theirs are kept with what they have."""
        while self._pending:
            self._send(self._pending.popleft())
        self._pos = self._count = 0
        self._idle_start = None
        self._next_idle = float("-inf")  # device time starts afresh: a limit in the old one would stop idle for long

    def _rows(self, first: int, last: int) -> np.ndarray:
        """Ring rows (chronological) of the frames numbered ``first`` .. ``last`` that it still holds."""
        n = min(self._count, self.capacity)
        rows = (self._pos - n + np.arange(n)) % self.capacity
        numbers = self._numbers[rows]
        return rows[np.searchsorted(numbers, first):np.searchsorted(numbers, last, side="right")]

    def _send(self, p: _Pending) -> None:
        layout = self.detector.layout
        rows = self._rows(p.start, p.end)
        if layout is None or not len(rows):
            return
        p.meta["report_frame"] = int(np.searchsorted(self._numbers[rows], p.report))
        self.writer.put(Capture(p.stem, self._frames[rows], self._stamps[rows] / 1000.0, layout,
                                {"subject": SUBJECT, META_KEY: p.meta}, trial=p.trial))

    def _idle(self, t: float) -> None:
        det = self.detector
        state = (bool(det.arm.moving), det.grasp_closed)
        if self._idle_start is None or state != self._idle_state or self._pending:
            self._idle_start, self._idle_state = (None if self._pending else t), state
            return
        if t - self._idle_start < 1000.0 * IDLE_S or t < self._next_idle or det.window_open:
            return
        rows = self._rows(-1, 1 << 62)
        rows = rows[self._stamps[rows] >= t - 1000.0 * IDLE_S]
        layout = det.layout
        self._idle_start, self._next_idle = t, t + self.idle_every_ms
        if layout is None:
            return
        moving, grasp = state
        source = "arm_move" if moving else "open" if grasp is False else "quiet"
        first = int(self._numbers[rows[0]])
        self.writer.put(Capture(idle_name(first, time.time()), self._frames[rows], self._stamps[rows] / 1000.0, layout,
                                {"subject": SUBJECT, META_KEY: {"kind": "idle", "instance": self.instance}},
                                stretch={"source": source, "arm_moving": moving, "grasp_closed": grasp,
                                         "frame_first": first}))

    # -- the control socket's and the ROS 2 node's threads ----------------------------------------
    def outcome(self, word: str, source: str) -> bool:
        """The robot's word about its last event (``outcome taken``): appended to outcomes.jsonl by the writer;
        an unknown word or no event to attach it to: refused, counted, logged (rate-limited). True: taken."""
        model = self.detector.model
        classes = tuple(model.meta.classes) if model is not None else ()
        stem = self.last_event
        problem = outcome_problem(word, classes)
        no_event = problem is None and stem is None
        if no_event:
            problem = f"outcome {word!r}: no event captured yet to attach it to; send it after an event"
        kind = "no event" if no_event else "unknown"
        said = self._said[1] + 1 if self._said[0] == stem else 1
        if problem is None and said > OUTCOMES_PER_EVENT:
            problem, kind = f"outcome {word!r}: {OUTCOMES_PER_EVENT} already said of {stem}; say one per event", "many"
        if problem is not None:
            self._refuse(f"{problem} (from {source}; not kept)", kind)
            return False
        self._said = (stem, said)
        return self.writer.put(Outcome({"event": stem, "outcome": word, "source": source, "time": time.time()}))

    def _refuse(self, line: str, kind: str) -> None:
        self.refused += 1
        now = time.monotonic()
        if now - self._refused_logged.get(kind, float("-inf")) >= REFUSED_LOG_S:
            self._refused_logged[kind] = now
            log.warning("capture: %s", line)
