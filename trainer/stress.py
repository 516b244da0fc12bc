"""Stress windows for the exported graph: the inputs where float32 arithmetic is most at risk.

Each family is a float32 ``[n, T, C]`` array of frames, built deterministically from a seed and
the model's codebook (windows exactly between two codewords need the codewords). Values stay
in the 12-bit range except the ``out_of_range`` family (what a corrupted frame could carry).
"""

from __future__ import annotations

import numpy as np

__all__ = ["stress_cases"]

FULL = 4095.0


def _midpoint_series(c_a: np.ndarray, c_b: np.ndarray, T: int, offset: float) -> np.ndarray:
    """A series whose first derivative window is exactly halfway between codewords a and b."""
    deriv = np.zeros(T - 1)
    deriv[: len(c_a)] = (c_a + c_b) / 2.0
    return offset + np.concatenate([[0.0], np.cumsum(deriv)])


def stress_cases(T: int, C: int, codebook: np.ndarray, seed: int = 0) -> dict[str, np.ndarray]:
    """Named families of stress windows, each float32 ``[n, T, C]``."""
    rng = np.random.default_rng(seed)
    codebook = np.asarray(codebook, dtype=np.float64)
    t = np.arange(T)[:, None]
    cases: dict[str, list[np.ndarray]] = {}

    def add(name: str, frames) -> None:
        cases.setdefault(name, []).append(np.broadcast_to(np.asarray(frames, dtype=np.float64), (T, C)))

    add("all_zero", 0.0)
    for c in sorted({0, C // 2, C - 1}):
        for value in (1.0, 600.0, FULL):
            one = np.zeros((T, C))
            one[:, c] = value
            add("one_active_taxel", one)
            ramp = np.zeros((T, C))
            ramp[:, c] = np.linspace(0.0, value, T)
            add("one_active_taxel", ramp)
    add("saturated", FULL)
    add("alternating_frames", np.where(t % 2 == 0, 0.0, FULL))
    add("alternating_frames", np.where(t % 2 == 0, FULL, 0.0))
    add("alternating_checker", np.where((t + np.arange(C)[None]) % 2 == 0, 0.0, FULL))
    add("constant_nonzero", rng.integers(1, 4096, C)[None].astype(float))
    add("constant_nonzero", 1.0)
    for offset in (2048.0, 4000.0, FULL - 1):
        add("noise_on_offset", offset + rng.normal(0.0, 1e-2, (T, C)))
        add("noise_on_offset", np.clip(offset + rng.integers(-1, 2, (T, C)), 0, FULL))
    step = np.where(t < T // 2, 0.0, FULL)
    add("max_step", step)
    add("max_step", FULL - step)
    add("uniform_random", rng.integers(0, 4096, (T, C)).astype(float))
    add("sparse_random", rng.integers(0, 4096, (T, C)) * (rng.random((T, C)) < 0.1))
    add("random_walk", np.clip(2048.0 + np.cumsum(rng.normal(0.0, 400.0, (T, C)), axis=0), 0.0, FULL).round())
    add("out_of_range", rng.uniform(-70000.0, 70000.0, (T, C)))
    n_words = len(codebook)
    for a in range(n_words):
        for b in range(a + 1, n_words):
            frames = np.zeros((T, C))
            series = _midpoint_series(codebook[a], codebook[b], T, offset=2048.0)
            frames[:, :: max(1, C // 4)] = series[:, None]
            add("between_codewords", frames)
    return {name: np.stack(items).astype(np.float32) for name, items in cases.items()}
