"""How sure a count of rare events is: the exact (Garwood) Poisson interval.

A handful of false events over minutes of idle gives a rate per hour whose uncertainty is as large
as the rate itself; a figure without its interval invites comparing noise. The bounds are the
Poisson means whose tail probabilities equal (1 - level) / 2: quantiles of the gamma distribution
(the chi-square form of the same bounds), from scipy, which the trainer already has through scikit-learn.
"""

from __future__ import annotations

__all__ = ["poisson_interval", "rate_interval"]


def poisson_interval(count: int, level: float = 0.95) -> tuple[float, float]:
    """Exact two-sided interval of a Poisson mean from ``count`` events: 0 -> (0, 3.689); 5 -> (1.623, 11.668)."""
    from scipy.special import gammaincinv

    if count < 0 or int(count) != count:
        raise ValueError(f"count must be a whole number >= 0, got {count}")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be within (0, 1), got {level}")
    tail = (1.0 - level) / 2.0
    k = int(count)
    lower = 0.0 if k == 0 else float(gammaincinv(k, tail))
    return lower, float(gammaincinv(k + 1, 1.0 - tail))


def rate_interval(count: int, hours: float, level: float = 0.95) -> tuple[float, float] | None:
    """The interval of a rate per hour (``count`` events in ``hours``); None when nothing was observed."""
    if not hours > 0.0:
        return None
    lower, upper = poisson_interval(count, level)
    return lower / hours, upper / hours
