"""The output half of the model contract, checked where a model is warmed up and at run time.

Why: a graph can pass every static check and still answer a label outside ``classes`` or NaN scores,
perhaps only on real frames. ``output_problem`` checks one decision (microseconds: every decision is
checked); ``probe`` runs the model on realistic windows at warm-up, checks each answer and times one
decision against a budget, so a bad or slow model is refused before it serves.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from runtime.health import one_line

__all__ = ["DEFAULT_BUDGET_FRACTION", "output_problem", "probe", "probe_windows"]

DEFAULT_BUDGET_FRACTION = 0.1
"""A decision may take at most this fraction of the model's sample period (3.1 ms at 32 Hz)."""
TIMED_RUNS = 7
"""Single-window decisions timed at warm-up; their median is compared with the budget."""


def output_problem(labels: Any, scores: Any, n_classes: int) -> str | None:
    """Why ``(labels, scores)`` of a batch breaks the contract, or None.

    The contract: ``labels`` int ``[N]`` with every value in ``0..n_classes-1``; ``scores``
    float ``[N, n_classes]``, all finite.
    """
    if _one_good_decision(labels, scores, n_classes):  # the daemon's case, in about a microsecond
        return None
    labels, scores = np.asarray(labels), np.asarray(scores)
    n = labels.shape[0] if labels.ndim == 1 else -1
    if labels.ndim != 1 or labels.dtype.kind not in "iu":
        return f"label output is {labels.dtype} {list(labels.shape)}, expected int64 [N]"
    if scores.shape != (n, n_classes) or scores.dtype.kind != "f":
        return f"scores output is {scores.dtype} {list(scores.shape)}, expected float [{n}, {n_classes}]"
    bad = (labels < 0) | (labels >= n_classes)
    if bad.any():
        return f"label {int(labels[bad][0])} is outside 0..{n_classes - 1} (the model has {n_classes} classes)"
    if not np.isfinite(scores).all():
        return f"scores contain {'NaN' if np.isnan(scores).any() else 'infinity'}"
    return None


_INT64, _FLOAT32 = np.dtype(np.int64), np.dtype(np.float32)
"""Compared as dtypes: ``dtype == np.int64`` converts the type to a dtype on every call."""


def _one_good_decision(labels: Any, scores: Any, n_classes: int) -> bool:
    """True for one in-range label with finite float32 scores (False: let the full check decide)."""
    return (type(labels) is np.ndarray and type(scores) is np.ndarray and labels.shape == (1,)
            and scores.shape == (1, n_classes) and labels.dtype == _INT64 and scores.dtype == _FLOAT32
            and 0 <= labels.item() < n_classes and bool(np.isfinite(scores).all()))


def probe_windows(T: int, n_channels: int, fullscale: float, seed: int = 0) -> np.ndarray:
    """Deterministic float32 ``[k, T, C]`` windows a real sensor could deliver.

    Non-zero on purpose: a model that is wrong only when the pads are pressed must fail here,
    not on the first real interaction.
    """
    rng = np.random.default_rng(seed)
    top = float(fullscale)
    ramp = np.linspace(0.0, 1.0, T, dtype=np.float32)[:, None]
    patch = np.zeros(n_channels, dtype=np.float32)
    patch[: max(1, n_channels // 3)] = 1.0
    windows = [
        np.zeros((T, n_channels)),
        ramp * patch * 0.6 * top,  # a press building up on one pad
        ramp[::-1] * patch * 0.6 * top,  # ... and its release
        np.full((T, n_channels), top),
        rng.integers(0, 24, (T, n_channels)),  # the noise floor of an untouched pad
        rng.integers(0, int(top) + 1, (T, n_channels)),
        np.round(np.clip(ramp * top * rng.random(n_channels)[None] + rng.normal(0, 30, (T, n_channels)), 0, top)),
    ]
    return np.ascontiguousarray(np.stack(windows), dtype=np.float32)


def probe(run: Any, T: int, n_channels: int, n_classes: int, fullscale: float, period_s: float,
          budget_fraction: float | None = DEFAULT_BUDGET_FRACTION) -> str | None:
    """Warm up ``run(window[1, T, C]) -> (labels, scores)``; why the model must not serve, or None.

    Every probe window's answer is checked against the contract; then one decision is timed
    ``TIMED_RUNS`` times. A median above ``budget_fraction * period_s`` is measured once more
    and refused only if the second median misses too. Timed by the calling thread's CPU clock: a
    decision that waited for a core (a busy machine, the daemon's hot loop holding the interpreter)
    is not the model's cost.
    """
    windows = probe_windows(T, n_channels, fullscale)
    for i, window in enumerate(windows):
        try:
            labels, scores = run(window[None])
        except Exception as exc:  # onnxruntime raises several unrelated types
            return f"fails on warm-up window {i}: {one_line(exc)}"
        problem = output_problem(labels, scores, n_classes)
        if problem:
            return f"breaks the output contract on warm-up window {i} of {len(windows)}: {problem}"
    if budget_fraction is None:
        return None
    budget = budget_fraction * period_s
    median = _median_decision(run, windows)
    if median > budget:
        median = min(median, _median_decision(run, windows))
    if median > budget:
        return (f"one decision takes {median * 1e3:.2f} ms at warm-up (median of {TIMED_RUNS}), over the budget of "
                f"{budget * 1e3:.2f} ms ({budget_fraction:g} of the {period_s * 1e3:.2f} ms sample period; "
                "model.decision_budget)")
    return None


def _median_decision(run: Any, windows: np.ndarray) -> float:
    times = []
    for i in range(TIMED_RUNS):
        window = windows[i % len(windows)][None]
        start = time.thread_time()
        run(window)
        times.append(time.thread_time() - start)
    return float(np.median(times))
