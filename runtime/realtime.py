"""Real-time scheduling of the hot path: a frame is handled the moment it arrives, not at the
scheduler's next slice.

Why: the daemon sleeps on the device and wakes per frame. On a loaded 2-core PC a normal thread
waits for a slice of the processes already running; niceness hardly helps. Under a real-time policy
the hot thread runs first. The price: on a quiet PC a FIFO thread waking from its sleep decides a
little later at the median. Tails under other work matter more to a robot than a fraction of a
period; set ``realtime_priority = 0`` on a PC with nothing else to do (figures:
results/design_figures.md and results/latency.md). Only the thread that calls :func:`enter_realtime` is raised (the model
watcher, which loads models, and the control socket keep normal scheduling, so loading a model
cannot hog a core), and with SCHED_RESET_ON_FORK nothing it starts afterwards inherits the
policy: neither threads (sinks a reload rebuilds) nor child processes, which at
the same priority would never yield the core back (a busy child of a real-time thread starves it).

The daemon raises its thread with a link's first valid frame and lowers it when the link fails,
so a device that floods the link with nonsense is parsed at normal priority.

Priority :data:`DEFAULT_PRIORITY` (1-99, 0 = normal scheduling): above every normal process and
below the kernel's interrupt threads (50 on PREEMPT_RT kernels) and a robot's control loops, which
are usually given more. The kernel's real-time throttling keeps 5 % of each second for the others
even if the thread never slept. Not permitted (neither root, CAP_SYS_NICE nor an RLIMIT_RTPRIO
that high: systemd's ``LimitRTPRIO=``, deploy/handover.service) or not available (not Linux): one
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
