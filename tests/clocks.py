"""A clock the test moves by hand: injected where code reads the time, so no test waits or races."""

from __future__ import annotations


class ManualClock:
    """Returns ``t`` when called; the test sets or advances ``t``."""

    def __init__(self, t: float = 0.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t
