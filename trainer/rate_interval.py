"""How sure a count of rare events is: the exact (Garwood) Poisson interval, numpy only.

A handful of false events over minutes of idle gives a rate per hour whose uncertainty is as large
as the rate itself; a figure without its interval invites comparing noise. The bounds are the
Poisson means whose tail probabilities equal (1 - level) / 2, found by bisection on the Poisson
distribution function (the chi-square form of the same bounds, without scipy).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["poisson_interval", "rate_interval"]


def _cdf(k: int, mu: float) -> float:
    """P(X <= k) for X ~ Poisson(mu), summed in logs (no overflow for large k or mu)."""
    if k < 0:
        return 0.0
    if mu <= 0.0:
        return 1.0
    i = np.arange(k + 1, dtype=np.float64)
    log_fact = np.concatenate(([0.0], np.cumsum(np.log(i[1:]))))
    logs = -mu + i * math.log(mu) - log_fact
    top = float(logs.max())
    return min(1.0, math.exp(top) * float(np.exp(logs - top).sum()))


def _solve(k: int, target: float) -> float:
    """The mean mu at which P(X <= k) = target (the distribution function falls as mu grows)."""
    lo, hi = 0.0, k + 10.0 * math.sqrt(k + 1.0) + 10.0
    while _cdf(k, hi) > target:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if _cdf(k, mid) > target:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-10 * max(1.0, hi):
            break
    return 0.5 * (lo + hi)


def poisson_interval(count: int, level: float = 0.95) -> tuple[float, float]:
    """Exact two-sided interval of a Poisson mean from ``count`` events: 0 -> (0, 3.689); 5 -> (1.623, 11.668)."""
    if count < 0 or int(count) != count:
        raise ValueError(f"count must be a whole number >= 0, got {count}")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be within (0, 1), got {level}")
    tail = (1.0 - level) / 2.0
    k = int(count)
    lower = 0.0 if k == 0 else _solve(k - 1, 1.0 - tail)
    return lower, _solve(k, tail)


def rate_interval(count: int, hours: float, level: float = 0.95) -> tuple[float, float] | None:
    """The interval of a rate per hour (``count`` events in ``hours``); None when nothing was observed."""
    if not hours > 0.0:
        return None
    lower, upper = poisson_interval(count, level)
    return lower / hours, upper / hours
