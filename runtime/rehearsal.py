"""Keep the hot path warm for the frame that completes a window: rehearse the model just before it
is due, then poll the device instead of sleeping until it arrives.

Why: at 32 Hz the hot thread idles 31 ms between frames; meanwhile other processes and the idle
core itself (on a virtual machine a halted vCPU leaves the host's caches to others) evict the
model's code and data, and a decision after that idle took about three times as long as one
back to back. Measured here (the default graph, all pads, alone in a process; medians): back to
back 57 us; after a 31 ms sleep 158 us; a rehearsal 2 ms before, then sleeping until the frame,
104 us; the same rehearsal followed by polling (the core never idles) 79 us. Warming the caches
is not enough when the core then sleeps; polling alone is not enough when the caches are cold.

Policy: when the trigger has fixed the due frame, its arrival is predictable (the measured stream
period after the frame before it: ``runtime.frame_rate.FrameClock.next_admitted_s``, ``expect``).
The hot thread reads as usual until a lead before that (and earlier by as long as the last
rehearsal took, so a slow model's rehearsal still ends before the frame instead of leaving it
unread, its arrival stamp late and the delay unmeasured), runs the rehearsal it was given (the
daemon's: the model on the current window, the output check, an event encoded, the client's receive
path; nothing sent or counted), then polls the device without blocking until the frame arrives or
``GRACE_S`` after its expected arrival, when it goes
back to blocking reads. Cost: at most ``LEAD_S + GRACE_S`` of one core per decision, nothing
per frame and nothing while no window is open. Everything runs in the hot thread: no thread to
start, to race with the ring, or to join at shutdown.

Continuous mode does not keep warm. Every frame is a decision there, so every frame would pay it: tried,
and against the real emulator at 32 Hz the daemon went from 1.5 % to 7.5-10 % of a core (21-34 % at
125 Hz), at SCHED_FIFO, for a median 344 -> 278 us per decision (the arrival jitter of a live link kept
the lead near its 2 ms maximum and late frames added the grace). A continuous-mode report waits for
``[continuous] confirm_frames`` frames anyway (8 by default: 250 ms), so those 70 us are not worth a
tenth of a core for months; its cold figures are in the latency bench's continuous-mode table.

The lead follows the stream: the polling between rehearsal and frame cools the caches again (the
paced stage table, frame parsed -> decision median: 168 us with a 2 ms lead, 153 us with 1 ms, 145 us
with 0.3 ms, frames on time), but a frame that comes earlier than the lead is decided cold, and one
that comes during the rehearsal waits for it. So the lead is ``LEAD_MARGIN_S`` more than the
earliest arrival of the last ``EARLY_HISTORY`` due frames against their expected time, between
``MIN_LEAD_S`` and ``LEAD_S`` (which it starts at, nothing measured).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from typing import Any, TypeVar

LEAD_S = 0.002
"""The longest lead (and the first, nothing measured yet): how long before the due frame's expected
arrival the rehearsal runs and polling starts; short enough that polling costs about 6 % of one core
while deciding."""
MIN_LEAD_S = 0.0003
"""The shortest lead: a frame exactly on time still finds the rehearsal done."""
LEAD_MARGIN_S = 0.0002
"""How much earlier than the earliest recent due frame the rehearsal ends."""
EARLY_HISTORY = 32
"""Due frames whose earliness sets the lead (about a minute of handovers)."""
GRACE_S = 0.002
"""How long after the expected arrival polling goes on before the thread blocks again (a late frame)."""

Item = TypeVar("Item")


class Rehearsal:
    """``expect(at, run)``: the frame that completes a window should arrive at ``perf_counter() == at``;
    ``read(read_fn, timeout)`` then reads the way this module's docstring says. ``cancel()`` drops the
    expectation (a reconnect, a model swap). ``runs``: rehearsals done; ``polled_s``: time spent polling."""

    def __init__(self, lead_s: float = LEAD_S, grace_s: float = GRACE_S) -> None:
        self.max_lead_s = lead_s
        self.grace_s = grace_s
        self._early: deque[float] = deque(maxlen=EARLY_HISTORY)
        """How early each recent due frame came (seconds before expected; late: negative)."""
        self._due: float | None = None
        self._run: Callable[[], Any] | None = None
        self.runs = 0
        self.polled_s = 0.0
        self.run_s = 0.0
        """How long the last rehearsal took: the next one starts that much before ``due - lead_s``."""

    @property
    def lead_s(self) -> float:
        """How long before the expected arrival the rehearsal ends and polling starts (module docstring)."""
        if not self._early:
            return self.max_lead_s
        return min(self.max_lead_s, max(MIN_LEAD_S, max(self._early) + LEAD_MARGIN_S))

    def _arrived(self, due: float, at: float) -> None:
        """Note a due frame's arrival; one earlier than the longest lead is taken for another frame
        (a device frame the decimation skips) and not noted."""
        if due - at <= self.max_lead_s:
            self._early.append(due - at)

    @property
    def due(self) -> float | None:
        """When the expected frame should arrive (``perf_counter`` seconds), or None."""
        return self._due

    def expect(self, at: float, run: Callable[[], Any]) -> None:
        self._due, self._run = at, run

    def cancel(self) -> None:
        self._due = self._run = None

    def read(self, read: Callable[[float], Item | None], timeout: float) -> Item | None:
        """``read(timeout)`` (the next item, or None after ``timeout`` s; 0 polls without blocking),
        warm around an expected frame. Returns what ``read`` returns; None may come before ``timeout``."""
        due = self._due
        if due is None:
            return read(timeout)
        clock = time.perf_counter
        now = clock()
        start = due - self.lead_s - self.run_s
        if now < start:
            item = read(min(timeout, start - now))
            if item is not None:
                self._arrived(due, clock())
            if item is not None or clock() < start:
                return item
        self._rehearse()
        began, stop = clock(), due + self.grace_s
        try:
            while clock() < stop:
                item = read(0.0)
                if item is not None:
                    self._arrived(due, clock())
                    return item
        finally:
            self.polled_s += clock() - began
        self.cancel()  # late: block as usual until it comes
        return None

    def _rehearse(self) -> None:
        run, self._run = self._run, None
        if run is None:
            return
        began = time.perf_counter()
        try:
            run()
            self.runs += 1
        except Exception:  # a failing model is the decision's business, not the rehearsal's
            pass
        finally:
            self.run_s = time.perf_counter() - began
