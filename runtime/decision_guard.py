"""Ends a decision that runs too long, from a thread of its own: the hot thread cannot.

Why: a model may pass load and warm-up and hang on real windows only (an ONNX ``Loop`` whose trip count
explodes), leaving the hot thread inside onnxruntime: no frame is read and SIGTERM waits. A decision that
spent more thread CPU time than the limit (one period; CPU time, so a busy machine does not quarantine a
good model), or ``WALL_LIMIT_S`` on the wall clock, is ended with ``RunOptions.terminate``; the hot thread
then takes the model out of service. A graph that does not stop when told is still running ``ESCALATE_S``
later: it is quarantined and the process exits with ``EXIT_HUNG`` (systemd restarts it).
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from typing import Any

from runtime import realtime
from runtime.background import Background

__all__ = ["DecisionGuard", "log"]

log = logging.getLogger("handover.daemon")

WALL_LIMIT_S = 1.0
"""The wall-clock backstop: about 32 periods, far beyond any wait for a core."""
ESCALATE_S = 5.0
"""How long an ended decision may take to stop before the process gives up."""
EXIT_HUNG = 3
MIN_LIMIT_S = 0.005


class DecisionGuard:
    """``check(now)`` ends the serving model's decision when it runs past ``limit_s()``; ``start()``
    runs the checks in a thread (at ``priority`` + 1 when the hot thread runs at real-time priority)."""

    def __init__(self, model: Callable[[], Any], limit_s: Callable[[], float],
                 on_stuck: Callable[[Any, str], None] | None = None, priority: int = 0,
                 clock: Callable[[], float] = time.perf_counter, exit: Callable[[int], None] = os._exit) -> None:
        self.model = model
        self.limit_s = limit_s
        self.on_stuck = on_stuck
        """Called with (model, reason) before the process exits over a decision that did not stop."""
        self.priority = int(priority)
        self.clock = clock
        self.exit = exit
        self.ended = 0
        """Decisions ended so far."""
        self._ended_at: float | None = None
        self._loop = Background("decision-guard", lambda: self.check(self.clock()), lambda: self.limit() / 4, log,
                                "decision guard check failed", on_start=self._enter_priority)

    def limit(self) -> float:
        return max(MIN_LIMIT_S, float(self.limit_s()))

    def check(self, now: float) -> None:
        """One look at the serving model's decision under way."""
        model = self.model()
        since = getattr(model, "running_since", None)
        if since is None:
            self._ended_at = None
            return
        if model.ended is None:
            limit = self.limit()
            cpu = model.decision_cpu_s()
            if cpu is not None and cpu > limit:
                reason = (f"a decision computed for longer than {limit * 1e3:.1f} ms (the stream's period) and was "
                          f"ended from outside (a graph that hangs on real frames?)")
            elif now - since > max(WALL_LIMIT_S, limit):
                reason = (f"a decision had not ended {now - since:.1f} s after it began and was ended from outside "
                          f"(a graph that hangs on real frames?)")
            else:
                reason = None
            if reason is not None:
                model.end_decision(reason)
                self.ended += 1
                self._ended_at = now
                log.error("model %s: %s", getattr(model, "model_id", "?"), reason)
            return
        if self._ended_at is not None and now - self._ended_at > ESCALATE_S:
            reason = f"a decision did not stop {ESCALATE_S:g} s after it was ended"
            log.critical("model %s: %s; the model is quarantined and the daemon exits (code %d) to be restarted",
                         getattr(model, "model_id", "?"), reason, EXIT_HUNG)
            if self.on_stuck is not None:
                self.on_stuck(model, reason)
            self.exit(EXIT_HUNG)

    def start(self) -> None:
        self._loop.start()

    def _enter_priority(self) -> None:
        if self.priority > 0:  # above the hot thread, or a hot thread spinning at real-time priority starves it
            realtime.enter_realtime(min(99, self.priority + 1))

    def stop(self, timeout: float = 0.5) -> None:
        self._loop.stop(timeout)
