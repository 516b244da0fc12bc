"""When a reader sends the push start again after push mode went silent on an open link.

A power-cycled DSACON32m comes back with acquisition stopped and its host has to ask again, as the
vendor's client does. It is deaf while it boots (about 8 s) and sends ESC[5n three times within
0.82 s about 7 s after power-on (SDHLibrary-Python ``dsa.py``). A try made while it is deaf is lost,
so once the boot codes come, tries wait for the boot to end instead of following the stall
schedule: a try at the schedule's next step could land just before the boot ends and push would
resume a whole step later.
"""

from __future__ import annotations

__all__ = ["BOOT_READY_S", "RESTART_STALLED_S", "PushRecovery"]

RESTART_STALLED_S = 2.0
"""Push mode silent this long on an open link: start it again."""
BOOT_READY_S = 1.2
"""After the first of the controller's power-up queries, it takes commands about a second later."""


class PushRecovery:
    """The restart schedule: ``due`` says when to try, ``tried`` records the outcome (times in seconds
    of one monotonic clock; ``boots`` is the parser's count of power-up queries)."""

    def __init__(self, stalled_s: float | None = RESTART_STALLED_S) -> None:
        self.stalled_s = stalled_s
        self.last_frame_at = 0.0
        self._boots_seen = 0
        self._boot_at: float | None = None  # the first power-up query of a boot, while it is not over

    def started(self, now: float, boots: int) -> None:
        """Push mode was (re)started: the clock of the stall schedule starts again, old boots are past."""
        self.last_frame_at, self._boots_seen, self._boot_at = now, boots, None

    def due(self, now: float, boots: int) -> bool:
        """Whether to send the push start now."""
        if self.stalled_s is None:
            return False
        if boots != self._boots_seen:
            self._boots_seen = boots
            if self._boot_at is None:  # the later queries of the same boot do not move it
                self._boot_at = now
        if self._boot_at is not None:
            return now - self._boot_at >= BOOT_READY_S
        return now - self.last_frame_at >= self.stalled_s

    def tried(self, now: float, ok: bool) -> bool:
        """Record a try made at ``now``; True when it restarted push after a boot (the device clock restarted)."""
        rebooted = self._boot_at is not None
        self.last_frame_at, self._boot_at = now, None  # a failed try: the stall schedule (or the next boot) decides
        return ok and rebooted
