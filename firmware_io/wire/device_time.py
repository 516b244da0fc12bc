"""The controller's clock: a wrapping u32 millisecond counter made monotonic."""

from __future__ import annotations

__all__ = ["TimestampUnwrapper"]


class TimestampUnwrapper:
    """Turns the device's wrapping u32 millisecond counter into a monotonic int.

    Each step is taken modulo 2**32 and read as signed, so a wrap (after ~49.7 days) adds
    2**32 and a small step backwards (reordering, a reset) stays small instead of jumping.
    """

    WRAP = 1 << 32

    def __init__(self) -> None:
        self._last_raw: int | None = None
        self._value = 0

    def reset(self) -> None:
        self._last_raw = None
        self._value = 0

    def __call__(self, raw: int) -> int:
        raw = int(raw) & 0xFFFFFFFF
        if self._last_raw is None:
            self._value = raw
        else:
            step = (raw - self._last_raw) % self.WRAP
            if step >= self.WRAP // 2:
                step -= self.WRAP
            self._value += step
        self._last_raw = raw
        return self._value
