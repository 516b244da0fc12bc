"""Random-convolution features in the MiniRocket spirit, as standard ONNX Conv ops.

MiniRocket (Dempster et al. 2021): 84 fixed zero-sum length-9 kernels at several dilations, each output
pooled by the proportion of positive values (PPV) above biases from quantiles of the training outputs
(levels ``frac(i * golden ratio)``). Here the series are the per-pad signals of ``trainer.features.signals``
(4 per pad, not hundreds of taxels), so extraction is one MatMul, one Conv per dilation, Sub, Greater
and ReduceMean: no window cutting. Features: ``[dilation][kernel][bias][series]``, each in [0, 1].
"""

from __future__ import annotations

from itertools import combinations

import numpy as np
from sklearn.utils import check_random_state

from trainer.features.base import FeatureFamily
from trainer.features.signals import SIGNALS, pad_signals, signal_error_bounds, signal_nodes
from trainer.numerics import SAFETY, U32, gamma

__all__ = ["RandomConvPPV", "minirocket_kernels"]

KERNEL_LENGTH = 9
MAX_FIT_CASES = 2000
"""Cases whose outputs set the bias quantiles (a seeded subset beyond this)."""


def minirocket_kernels() -> np.ndarray:
    """The 84 MiniRocket kernels ``(84, 9)``: weight 2 at three positions, -1 elsewhere."""
    out = np.full((84, KERNEL_LENGTH), -1.0)
    for k, idx in enumerate(combinations(range(KERNEL_LENGTH), 3)):
        out[k, list(idx)] = 2.0
    return out


def convolve_same(s: np.ndarray, kernels: np.ndarray, dilation: int) -> np.ndarray:
    """``(n, S, T)`` series -> ``(n, K, T, S)``: zero-padded ("same") dilated correlation, as ONNX Conv."""
    n, n_sig, n_t = s.shape
    half = (KERNEL_LENGTH // 2) * dilation
    padded = np.concatenate([np.zeros((n, n_sig, half)), s, np.zeros((n, n_sig, half))], axis=2)
    taps = np.stack([padded[:, :, j * dilation : j * dilation + n_t] for j in range(KERNEL_LENGTH)], axis=-1)
    return np.einsum("nstj,kj->nkts", taps, kernels)


def convolve_magnitude(s: np.ndarray, kernels: np.ndarray, dilation: int) -> np.ndarray:
    """sum_j |w_j| |s[t + j d]|: the scale of each output's float32 rounding error, ``(n, K, T, S)``."""
    return convolve_same(np.abs(s), np.abs(kernels), dilation)


def sorted_quantiles(ordered: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``np.quantile`` (linear method) of each row of ``ordered`` ``(..., M)`` (sorted) at its own
    level ``q`` ``(...)``."""
    pos = q * (ordered.shape[-1] - 1)
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, ordered.shape[-1] - 1)
    a = np.take_along_axis(ordered, lo[..., None], axis=-1)[..., 0]
    b = np.take_along_axis(ordered, hi[..., None], axis=-1)[..., 0]
    return a + (pos - lo) * (b - a)


class RandomConvPPV(FeatureFamily):
    """MiniRocket-style PPV features of the per-pad signals.

    Parameters: ``dilations`` (tuple), ``n_biases`` (per kernel, dilation and series),
    ``random_state`` (the case subset for the quantiles), ``pad_sizes``/``pad_shapes``, ``fullscale``.
    Fitted: ``biases_`` ``(D, 84, n_biases, S)``.
    """

    learns_from_cases = True  # the biases are quantiles of the training cases' outputs

    def __init__(self, dilations=(1, 2), n_biases: int = 1, random_state=0, pad_sizes=None, pad_shapes=None,
                 fullscale: float = 4095.0):
        self.dilations = dilations
        self.n_biases = n_biases
        self.random_state = random_state
        self.pad_sizes = pad_sizes
        self.pad_shapes = pad_shapes
        self.fullscale = fullscale

    def _dilations(self) -> tuple[int, ...]:
        d = tuple(int(v) for v in np.atleast_1d(self.dilations))
        if not d or min(d) < 1 or len(set(d)) != len(d):
            raise ValueError(f"dilations must be distinct integers >= 1, got {self.dilations!r}")
        return d

    def _fit(self, X, y) -> None:
        if int(self.n_biases) < 1:
            raise ValueError(f"n_biases must be >= 1, got {self.n_biases}")
        rng = check_random_state(self.random_state)
        if len(X) > MAX_FIT_CASES:
            X = X[np.sort(rng.choice(len(X), MAX_FIT_CASES, replace=False))]
        s = pad_signals(X, self.shapes_, float(self.fullscale))
        kernels = minirocket_kernels()
        n_sig = s.shape[1]
        dilations = self._dilations()
        levels = (np.arange(1, len(dilations) * 84 * int(self.n_biases) * n_sig + 1) * 0.6180339887498949) % 1
        levels = levels.reshape(len(dilations), 84, int(self.n_biases), n_sig)
        biases = np.empty_like(levels)
        for i, d in enumerate(dilations):
            out = convolve_same(s, kernels, d)  # (n, K, T, S)
            pooled = out.transpose(1, 3, 0, 2).reshape(84, n_sig, -1)  # (K, S, n*T)
            ordered = np.sort(pooled, axis=2)
            for b in range(int(self.n_biases)):
                biases[i, :, b, :] = sorted_quantiles(ordered, levels[i, :, b, :])
        self.biases_ = biases
        self.n_features_out_ = int(biases.size)

    def _transform(self, X: np.ndarray) -> np.ndarray:
        s = pad_signals(X, self.shapes_, float(self.fullscale))
        kernels = minirocket_kernels()
        parts = []
        for i, d in enumerate(self._dilations()):
            out = convolve_same(s, kernels, d)[:, :, None]  # (n, K, 1, T, S)
            parts.append((out > self.biases_[i][None, :, :, None, :]).mean(axis=3).reshape(len(X), -1))
        return np.concatenate(parts, axis=1)

    def error_bounds(self, X) -> np.ndarray:
        """Share of each feature's positions whose output is within SAFETY x its float32 error
        bound of the bias (a near tie: the graph may count it either way)."""
        X = self._check(X)
        s = pad_signals(X, self.shapes_, float(self.fullscale))
        e = signal_error_bounds(X, self.shapes_, float(self.fullscale))
        kernels = minirocket_kernels()
        parts = []
        for i, d in enumerate(self._dilations()):
            out = convolve_same(s, kernels, d)[:, :, None]
            bound = (convolve_same(e, np.abs(kernels), d) + gamma(KERNEL_LENGTH + 2)
                     * convolve_magnitude(s, kernels, d))[:, :, None] + U32 * np.abs(self.biases_[i])[None, :, :, None, :]
            near = np.abs(out - self.biases_[i][None, :, :, None, :]) <= SAFETY * bound
            parts.append(near.mean(axis=3).reshape(len(X), -1))
        return np.concatenate(parts, axis=1)

    def onnx_nodes(self, g, frames: str) -> str:
        sig = signal_nodes(g, frames, self.shapes_, float(self.fullscale))  # [N, T, S]
        x4 = g.op("Unsqueeze", [sig, g.const("axis1", [1], np.int64)], "signals4")  # [N, 1, T, S]
        weights = g.const("rocket_kernels", minirocket_kernels().reshape(84, 1, KERNEL_LENGTH, 1))
        n_feat = 84 * int(self.n_biases) * len(SIGNALS) * len(self.shapes_)
        parts = []
        for i, d in enumerate(self._dilations()):
            half = (KERNEL_LENGTH // 2) * d
            conv = g.op("Conv", [x4, weights], "rocket_conv", dilations=[d, 1], pads=[half, 0, half, 0])  # [N,K,T,S]
            conv5 = g.op("Unsqueeze", [conv, g.const("axis2", [2], np.int64)], "rocket_conv5")  # [N, K, 1, T, S]
            bias = g.const("rocket_bias", self.biases_[i][None, :, :, None, :])  # [1, K, B, 1, S]
            above = g.op("Cast", [g.op("Greater", [conv5, bias], "rocket_above")], "rocket_positive", to=1)
            ppv = g.op("ReduceMean", [above], "rocket_ppv", axes=[3], keepdims=0)  # [N, K, B, S]
            parts.append(g.op("Reshape", [ppv, g.const("ppv_shape", [0, n_feat], np.int64)], "rocket_features"))
        return g.op("Concat", parts, "rocket", axis=1) if len(parts) > 1 else parts[0]
