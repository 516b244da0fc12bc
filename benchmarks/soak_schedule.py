"""The soak benchmark's schedule: which fault, model drop or reload comes next, and when.

A fault waits for the one before it to be over: every TCP close power-cycles the emulated
controller (an 8 s boot, docs/EMULATOR.md), so faults 6 s apart overlapped, and a 72 s smoke run
streamed about 20 s, none of it long enough after a recovery for an event to be checked. The next
fault starts once the daemon has handled a frame sent after the last one ended (it recovered) and
then CLEAN_AFTER_FAULT_S of frames; an hour's run, a fault a minute, is unchanged by this.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from benchmarks.soak_account import RECOVERY_LIMIT_S

CLEAN_HISTORY_S = 4.0
"""An event is expected only where the daemon handled every frame of this long before it, clean."""
CLEAN_AFTER_FAULT_S = 2 * CLEAN_HISTORY_S
"""After a recovery the next fault waits this long of handled frames: a clean history, then as
long again in which the events the reference decides are expected (and checked)."""
LAST_FAULT_BEFORE_END_S = 30.0
"""No fault starts in the run's last 30 s: the slowest (a 15 s garbage stream, then the 8 s boot)
must have recovered before the end."""
FAULT_KINDS = ("disconnect", "stall_short", "crc", "stall_long", "garbage_burst", "drop", "garbage_stream", "hang")
SWAPS = ("good_b", "truncated", "good_a", "random_bytes", "good_b", "rollback", "empty", "world_writable")
"""Model drops in turn: good ones, broken ones (which must leave the model in use serving) and a
rollback as docs/GUIDE.md says (the newest file removed while b serves: a, the newest valid file
left, must serve)."""


@dataclass
class Fault:
    kind: str
    start: float
    end: float = 0.0
    recovered_at: float | None = None
    detail: dict = field(default_factory=dict)


@dataclass
class Plan:
    """When things happen, scaled to the run's length (an hour: a fault a minute, a swap every
    2.5 min, a reload every 4 min; a short smoke run squeezes them, hangs need two minutes)."""

    seconds: float
    fault_every: float
    swap_every: float
    hup_every: float
    hangs: bool

    @classmethod
    def for_hours(cls, hours: float) -> Plan:
        s = hours * 3600.0
        return cls(seconds=s, fault_every=min(60.0, max(6.0, s / 50)), swap_every=min(150.0, max(8.0, s / 20)),
                   hup_every=min(240.0, max(10.0, s / 12)), hangs=s >= 120)


class Schedule:
    """What the soak does next (a fault, a model drop or a reload, in that precedence), read off
    ``clock`` (the soak's loop passes time.monotonic, tests a manual clock) from ``t0`` (default: now),
    the run's start: it never waits."""

    def __init__(self, plan: Plan, clock: Callable[[], float] = time.monotonic, t0: float | None = None) -> None:
        self.plan, self.clock = plan, clock
        self.t0 = clock() if t0 is None else t0
        self.kinds = [k for k in FAULT_KINDS if k != "hang" or plan.hangs]
        self.next_fault = self.t0 + plan.fault_every / 2
        self.next_swap, self.next_hup = self.t0 + plan.swap_every, self.t0 + plan.hup_every
        self.n_fault = self.n_swap = 0
        self.last: Fault | None = None
        self.recovered_at: float | None = None
        """Arrival of the first frame the daemon handled that was sent after ``last`` ended."""
        self.handled_to = -math.inf
        """Send time of the newest frame the daemon handled."""

    def handled(self, sent_t: float, arrival_t: float) -> None:
        """The daemon handled the frame sent at ``sent_t`` (arrived at ``arrival_t``)."""
        self.handled_to = max(self.handled_to, sent_t)
        if self.last is not None and self.recovered_at is None and sent_t > self.last.end:
            self.recovered_at = arrival_t

    def quiet(self) -> bool:
        """The last fault recovered and the daemon then handled CLEAN_AFTER_FAULT_S of frames (or it
        never recovered within the accounting's limit: it counts as not recovered, the run goes on)."""
        last = self.last
        if last is None or self.clock() - last.end > RECOVERY_LIMIT_S:
            return True
        return self.recovered_at is not None and self.handled_to >= self.recovered_at + CLEAN_AFTER_FAULT_S

    def due(self) -> tuple[str, str] | None:
        """("fault", kind), ("swap", what) or ("reload", "") when one is due, else None. A fault is
        counted once ``injected``; a swap or reload as it is returned."""
        now, p = self.clock(), self.plan
        if now >= self.next_fault and now - self.t0 < p.seconds - LAST_FAULT_BEFORE_END_S and self.quiet():
            return "fault", self.kinds[self.n_fault % len(self.kinds)]
        if now >= self.next_swap and now - self.t0 < p.seconds - 20:
            self.n_swap += 1
            self.next_swap += p.swap_every
            return "swap", SWAPS[(self.n_swap - 1) % len(SWAPS)]
        if now >= self.next_hup and now - self.t0 < p.seconds - 20:
            self.next_hup += p.hup_every
            return "reload", ""
        return None

    def injected(self, fault: Fault) -> None:
        """``fault`` is on (its ``end`` set; bursts and hangs return once over): the next waits for it."""
        self.last, self.recovered_at = fault, None
        self.n_fault += 1
        self.next_fault = self.clock() + self.plan.fault_every
