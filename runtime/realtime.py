"""Real-time scheduling of the hot path: a frame is handled the moment it arrives, not at the next slice.

Why: on a loaded 2-core PC a normal thread waits for the processes already running; under a real-time
policy the hot thread runs first, at a small cost to the median on a quiet PC (results/latency.md; set
``realtime_priority = 0`` there). Only the calling thread is raised, with SCHED_RESET_ON_FORK so no
thread or child it starts inherits the policy (a real-time child would starve it). The daemon raises
it with a link's first valid frame and lowers it when the link fails. :data:`DEFAULT_PRIORITY` is
above normal processes and below interrupt threads and control loops. Not permitted or not Linux: one
line says so and the daemon runs at normal priority.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass

__all__ = ["DEFAULT_PRIORITY", "HotThread", "Scheduling", "current", "enter_realtime", "restore"]

DEFAULT_PRIORITY = 20
"""The config's ``realtime_priority`` unless set (0 turns it off)."""


@dataclass(frozen=True)
class Scheduling:
    """A thread's policy and priority, as ``os.sched_getscheduler`` / ``sched_getparam`` say."""

    policy: int
    priority: int


def current() -> Scheduling | None:
    """The calling thread's scheduling, or None where the platform cannot tell."""
    try:
        policy = os.sched_getscheduler(0) & ~getattr(os, "SCHED_RESET_ON_FORK", 0)
        return Scheduling(policy, os.sched_getparam(0).sched_priority)
    except (AttributeError, OSError):
        return None


def enter_realtime(priority: int) -> tuple[Scheduling | None, str]:
    """Put the calling thread under SCHED_FIFO at ``priority`` (0: leave it as it is).

    Returns the scheduling to restore with :func:`restore` and one line for the log."""
    before = current()
    if priority <= 0:
        return before, "normal scheduling (realtime_priority = 0)"
    if before is None or not hasattr(os, "SCHED_FIFO"):
        return None, "real-time scheduling is not available on this platform: normal scheduling"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0), os.sched_param(priority))
    except OSError as exc:
        return None, (f"real-time scheduling (SCHED_FIFO {priority}) not permitted ({exc.strerror}): normal "
                      "scheduling; allow it with LimitRTPRIO= in the service (deploy/handover.service) or set "
                      "realtime_priority = 0 to silence this")
    return before, f"hot path at real-time priority (SCHED_FIFO {priority})"


def restore(previous: Scheduling | None) -> None:
    """Give the calling thread back the scheduling :func:`enter_realtime` found (best effort)."""
    if previous is None:
        return
    with contextlib.suppress(AttributeError, OSError):
        os.sched_setscheduler(0, previous.policy, os.sched_param(previous.priority))


class HotThread:
    """The calling thread's ``realtime_priority``: ``raise_`` with a link's first valid frame (a device
    that sends only garbage never gets the CPU at real-time priority), ``lower`` when the link fails or
    the daemon stops. ``raise_`` returns the log line the first time a priority is applied, else None."""

    def __init__(self) -> None:
        self.applied = False
        self._before: Scheduling | None = None
        self._logged: int | None = None

    def raise_(self, priority: int) -> str | None:
        before, line = enter_realtime(priority)
        self.applied = True
        self._before = before if priority > 0 else None
        if self._logged == priority:
            return None
        self._logged = priority
        return line

    def lower(self) -> None:
        if self._before is not None:
            restore(self._before)
        self.applied, self._before = False, None
