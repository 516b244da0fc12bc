"""How sure a count is: the exact (Garwood) Poisson interval of a rate, the exact (Clopper-Pearson)
binomial interval of a share.

A handful of false events over minutes of idle gives a rate per hour whose uncertainty is as large
as the rate itself, and 22 right of 25 cannot tell a share of 0.88 from 0.92; a figure
without its interval invites comparing noise. The bounds are the means (shares) whose tail
probabilities equal (1 - level) / 2, from scipy (gamma quantiles; ``binomtest``), which the trainer
already has through scikit-learn.
"""

from __future__ import annotations

__all__ = ["poisson_interval", "proportion_interval", "rate_interval"]


def _tail(count: int, level: float) -> float:
    if count < 0 or int(count) != count:
        raise ValueError(f"count must be a whole number >= 0, got {count}")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be within (0, 1), got {level}")
    return (1.0 - level) / 2.0


def poisson_interval(count: int, level: float = 0.95) -> tuple[float, float]:
    """Exact two-sided interval of a Poisson mean from ``count`` events: 0 -> (0, 3.689); 5 -> (1.623, 11.668)."""
    from scipy.special import gammaincinv

    tail = _tail(count, level)
    k = int(count)
    lower = 0.0 if k == 0 else float(gammaincinv(k, tail))
    return lower, float(gammaincinv(k + 1, 1.0 - tail))


def rate_interval(count: int, hours: float, level: float = 0.95) -> tuple[float, float] | None:
    """The interval of a rate per hour (``count`` events in ``hours``); None when nothing was observed."""
    if not hours > 0.0:
        return None
    lower, upper = poisson_interval(count, level)
    return lower / hours, upper / hours


def proportion_interval(count: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Exact (Clopper-Pearson) interval of a share from ``count`` successes in ``n`` trials: 22 of 25 -> (0.688, 0.975)."""
    from scipy.stats import binomtest

    _tail(count, level)
    if int(n) != n or n < max(count, 1):
        raise ValueError(f"n must be a whole number >= max(count, 1), got {n} for count {count}")
    ci = binomtest(int(count), int(n)).proportion_ci(confidence_level=level, method="exact")
    return float(ci.low), float(ci.high)
