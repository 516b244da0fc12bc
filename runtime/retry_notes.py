"""Which failed connection attempts are worth a log line (used by runtime.device_link).

Why: a warning per retry (six a minute, forever) would bury the journal. The first failure is logged,
the same words again only after each of ``REPEAT_NOTES_S``, a new reason at once, and the connection
that ends the outage says how long it lasted. The health file hears of every attempt (from the caller).
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable

__all__ = ["QUIET", "RetryNotes"]

REPEAT_NOTES_S = (60.0, 600.0, 3600.0)
"""The same failure is logged again this long after it began; after the last step, once per last step."""
QUIET = f" (and again quietly: the next line after {REPEAT_NOTES_S[0]:.0f} s, or at once for a new reason)"
"""Said with an outage's first line: a console silent for the next minute is the daemon retrying, not hung."""


class RetryNotes:
    """The failed attempts of one outage, and when the next line about them is due."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self.clock = clock
        self.reset()

    def reset(self) -> None:
        """Forget the outage (a new device URL starts afresh)."""
        self.attempts = 0
        self.reason: str | None = None
        self._kinds: set[str] = set()
        self._outage_start = 0.0
        self._reason_start = 0.0
        self._notes = 0
        self._next_note = 0.0

    def failed(self, reason: str, retry_in_s: float) -> str | None:
        """Count a failed attempt; the line to log after ``device URL: ``, or None to stay quiet."""
        now = self.clock()
        if self.attempts == 0:
            self._outage_start = now
        self.attempts += 1
        kind = _kind(reason)
        if kind not in self._kinds:
            self._kinds.add(kind)
            self.reason, self._reason_start, self._notes = reason, now, 0
            self._next_note = now + REPEAT_NOTES_S[0]
            return f"{reason}; retrying in {retry_in_s:.1f} s{QUIET}"
        self.reason = reason  # the latest words, for "last:"
        if now < self._next_note:
            return None
        self._notes += 1
        if self._notes < len(REPEAT_NOTES_S):
            self._next_note = self._reason_start + REPEAT_NOTES_S[self._notes]
        else:
            self._next_note = now + REPEAT_NOTES_S[-1]
        return (f"still unreachable after {self.attempts} attempts in {_span(now - self._outage_start)} "
                f"(last: {reason}); retrying every {retry_in_s:.1f} s")

    def connected(self) -> str:
        """`` after N failed attempts in T`` for the line that says the device is back ("" if none failed);
        the outage ends."""
        if self.attempts == 0:
            return ""
        text = f" after {self.attempts} failed attempt{'s' if self.attempts > 1 else ''} in " \
               f"{_span(self.clock() - self._outage_start)}"
        self.reset()
        return text


def _kind(reason: str) -> str:
    """A failure's words without its numbers: the same failure whatever it counted this time."""
    return re.sub(r"0x[0-9A-Fa-f]+|\d+(\.\d+)?", "#", reason)


def _span(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"
