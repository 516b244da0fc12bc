"""A rehearsal of the model just before the frame that completes a window is due, so the decision
runs on warm caches.

Why: at 32 Hz the daemon idles 31 ms between frames; other processes and the CPU's sleep states
evict the model's code and data meanwhile, and a decision after that idle took about twice as
long as one back to back (results/latency.md, "paced"). When the trigger has fixed the due frame,
its arrival is predictable (one sample period after the frame before it); a background thread
runs the model once on the current window ``lead_s`` before that, result discarded. Cost: one
extra inference per decision (not per frame), in a thread that otherwise sleeps.

onnxruntime releases the GIL while it runs, so the main thread is not held up if the frame
arrives during the rehearsal; a session may be run from two threads at once. The window is a
view of the ring the main thread keeps writing: a rehearsal may see a frame half-written, which
does not matter as its answer is thrown away.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

REHEARSAL_LEAD_S = 0.002
"""How long before the due frame's expected arrival the rehearsal runs: more than the arrival
jitter of a 32 Hz stream, short enough that the caches it fills are still warm."""
IDLE_S = 5.0
"""A thread with nothing scheduled for this long ends (the next schedule starts another): a
daemon that is dropped without ``shutdown`` (replays, benchmarks, tests make thousands) leaves
no thread behind; it is also the longest single wait."""

CLOSE_WAIT_S = 0.2
"""Longest a shutdown waits for a running rehearsal (a decision takes about a millisecond; SIGTERM
must end the process within a second)."""


class Rehearsal:
    """``schedule(run, at)``: call ``run()`` at ``time.perf_counter() == at`` in a background thread
    (a newer schedule replaces an older one; ``cancel()`` drops it). ``runs``: rehearsals done."""

    def __init__(self) -> None:
        self._wake = threading.Condition()
        self._job: tuple[Callable[[], Any], float] | None = None
        self._thread: threading.Thread | None = None
        self._closing = False
        self.runs = 0

    def schedule(self, run: Callable[[], Any], at: float) -> None:
        with self._wake:
            self._job = (run, at)
            if self._thread is None:
                self._thread = threading.Thread(target=self._loop, name="handover-rehearsal", daemon=True)
                self._thread.start()
            self._wake.notify()

    def cancel(self) -> None:
        if self._job is not None:
            with self._wake:
                self._job = None

    def close(self, timeout: float = CLOSE_WAIT_S) -> None:
        """Drop any schedule, let the thread end and wait up to ``timeout`` for a rehearsal still
        running (the daemon's shutdown): a process that exits while onnxruntime runs a session in
        another thread aborts ("terminate called without an active exception", SIGABRT)."""
        with self._wake:
            self._job = None
            thread = self._thread
            self._closing = thread is not None
            self._wake.notify()
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout)

    def _loop(self) -> None:
        while True:
            with self._wake:
                idle_until = time.perf_counter() + IDLE_S
                while self._job is None:
                    left = idle_until - time.perf_counter()
                    if self._closing or left <= 0:
                        self._thread, self._closing = None, False
                        return
                    self._wake.wait(left)
                run, at = self._job
                delay = at - time.perf_counter()
                if delay > 0:
                    self._wake.wait(min(delay, IDLE_S))  # woken early by a newer job or a cancel: look again
                    if self._job is None or self._job[1] != at or time.perf_counter() < at:
                        continue
                self._job = None
            try:
                run()
                self.runs += 1
            except Exception:  # a failing model is the decision's business, not the rehearsal's
                pass
