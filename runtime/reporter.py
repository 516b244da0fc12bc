"""From a detector's decision to the outside world: health counters, the event line, the sinks.

The service's half of the hot path (the detector's is runtime/detector.py): every decision is
counted with its latency; a reported one becomes an ``Event``, is encoded once and handed to
every sink; listeners (runtime.listeners) then get the decision's stage stamps. Each stage is
stamped, so the latency benchmark splits the real path without a copy of it.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from runtime.detector import Decision
from runtime.health import Latency
from runtime.listeners import FrameListener
from runtime.sinks import Event, SinkSet

__all__ = ["Reporter"]


def event_of(decision: Decision) -> Event:
    """The decision line of a reported decision."""
    model, frame = decision.model, decision.frame
    classes = model.meta.classes
    return Event(time.time(), classes[decision.report], dict(zip(classes, decision.scores[0].tolist(), strict=True)),
                 decision.latency_us, model.model_id, decision.first, frame.number, int(frame.timestamp_ms),
                 decision.missed)


class Reporter:
    """``report(decision)``: counted here (``counters``); a reported class sent to ``sinks`` as an event (and
    to ``on_event``); every listener told. ``sinks`` may be replaced between frames (a reload)."""

    def __init__(self, sinks: SinkSet, on_event: Callable[[Event], None] | None = None,
                 listeners: list[FrameListener] | None = None) -> None:
        self.sinks = sinks
        self.decisions = 0
        self.events = 0
        self.missed_deadlines = 0
        self.latency = Latency()
        self.on_event = on_event
        self.listeners: list[FrameListener] = listeners if listeners is not None else []

    def report(self, decision: Decision) -> None:
        clock = time.perf_counter
        self.decisions += 1
        self.latency.record(decision.latency_us)
        if decision.missed:
            self.missed_deadlines += 1
        stamps = decision.timings
        if decision.report >= 0:
            event = event_of(decision)
            stamps.built = clock()
            encoded = self.sinks.encode(event)
            stamps.serialised = clock()
            self.events += 1
            if encoded is not None:
                self.sinks.send(*encoded)
            stamps.sent = clock()
            if self.on_event is not None:
                self.on_event(event)
        for listener in self.listeners:
            listener.on_decision(decision)

    def counters(self) -> dict[str, int | float | None]:
        return {"decisions": self.decisions, "events": self.events, "missed_deadlines": self.missed_deadlines,
                **self.latency.counters()}
