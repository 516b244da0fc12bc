"""How a rate of events is written wherever one is shown (train's console and report, the model card,
``run --check``, results): the rate with the count and the hours it comes from beside it.

Why: "24.9 per hour" from 4 events in 9.6 minutes reads like a measured hour; "24.9/h (4 in 0.16 h)"
says how little it rests on. In the runtime because ``inspect`` and ``run --check`` print it on the lean
install.
"""

from __future__ import annotations

__all__ = ["rate_text"]


def _hours_text(hours: float) -> str:
    """``0.16 h``, ``2.16 h``: two significant digits below an hour (0.013 h stays readable), else two decimals."""
    return f"{hours:.2f} h" if hours >= 1.0 else f"{hours:.2g} h"


def rate_text(events: int, hours: float | None, digits: int = 1) -> str:
    """``24.9/h (4 in 0.16 h)``; ``-/h (none observed)`` when no time was observed."""
    if not hours or hours <= 0.0:
        return "-/h (none observed)"
    return f"{events / hours:.{digits}f}/h ({events} in {_hours_text(hours)})"
