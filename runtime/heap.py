"""When the garbage collector runs: at start-up once, then only between windows, never on its own.

Why: CPython collects the young generation whenever 700 more objects were allocated than freed,
wherever that happens; in the daemon that was about once per 600 frames, 100 us each (213 us at
worst), a middle generation 0.8 ms and a full one 7 ms in the latency benchmark's process. One
such pause inside a decision is the decision's p99.9. So the daemon hides start-up's objects from
the collector (``gc.freeze``), turns automatic collection off, and collects itself from its loop:
the young generations every ``YOUNG_PERIOD_S``, everything every ``FULL_PERIOD_S``, only while no
window is open (between frames there are 31 ms; a collection takes at most a few) and not within
``CLEARANCE_S`` of a due frame. A stream that keeps windows open, or a trigger that makes every next
frame a due one, still gets one ``MAX_DEFER_S`` after it was due (about every 11 s; a due frame used to
hold a collection back for ever). Reference counting frees almost everything at once anyway; the collector is
only for cycles.
"""

from __future__ import annotations

import gc

YOUNG_PERIOD_S = 1.0
FULL_PERIOD_S = 60.0


def settle_heap() -> None:
    """Collect once, hide every object alive now (modules, model, config) from the collector and
    turn automatic collection off (``GarbageSchedule`` collects from then on).

    Why freeze: the older generations re-scan every long-lived object when they run; a full
    collection took 6.6 ms in the latency benchmark's process, 1 us after freezing."""
    gc.collect()
    gc.freeze()
    gc.disable()


def release_heap() -> None:
    """Automatic collection on again when the daemon stops (in-process callers: tests, replays). The
    frozen start-up objects stay frozen; ``gc.unfreeze()`` is the caller's if it wants them scanned."""
    gc.enable()


MAX_DEFER_S = 10.0
"""A collection kept waiting this long by windows that stay open (a trigger that fires all the
time) or by due frames always within the clearance runs anyway."""
CLEARANCE_S = 0.01
"""No collection when a due frame is expected sooner than this: a collection takes at most a few ms
(7 ms for a full one before ``gc.freeze``), and the rehearsal starts up to ``LEAD_S`` plus its own run
before the frame (runtime.rehearsal)."""


class GarbageSchedule:
    """``collect(now, window_open, due_in)``: collect what is due, unless a window is open or a due
    frame is expected within ``CLEARANCE_S`` (``due_in``, seconds; None: none expected): then later,
    at most ``MAX_DEFER_S`` late."""

    def __init__(self) -> None:
        self._young_due: float | None = None
        self._full_due = 0.0
        self.collections = 0

    def collect(self, now: float, window_open: bool, due_in: float | None = None) -> None:
        if self._young_due is None:  # the first call: everything is due from now on
            self._young_due = self._full_due = now
        if now < self._young_due:
            return
        held = window_open or (due_in is not None and due_in < CLEARANCE_S)
        if held and now < self._young_due + MAX_DEFER_S:
            return
        full = now >= self._full_due
        gc.collect(2 if full else 1)
        self.collections += 1
        self._young_due = now + YOUNG_PERIOD_S
        if full:
            self._full_due = now + FULL_PERIOD_S
