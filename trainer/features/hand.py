"""The paper's hand-designed baseline features (``trainer.baseline.pad_features``: 14 per pad) as
ONNX nodes, so the baseline ships as one graph like every other family.

Per pad: max, mean and standard deviation of all taxel values (ReduceMax/ReduceMean), the median
(TopK of the largest half, then the middle one or two), the FFT band shares and log energy of the
pad's mean-pressure signal (two MatMuls with cosine/sine matrices: a DFT, not an FFT op), the mean
derivative ((last - first) / (T - 1), the telescoped mean of the differences), and the centre of
pressure (Where for an empty pad), its net displacement and mean speed.
"""

from __future__ import annotations

import numpy as np

from trainer.baseline import FEATURES_PER_PAD, pad_features
from trainer.features.base import FeatureFamily, pad_bounds, slice_nodes
from trainer.numerics import SAFETY, U32, gamma


def dft_matrices(n_t: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cosine and sine ``[T, B]`` of rfft bins 1 .. T//2 and the band indicator ``[B, 3]`` of
    ``pad_features`` (thirds by ``np.array_split``; all bins in each band when fewer than 3)."""
    bins = np.arange(1, n_t // 2 + 1)
    angle = 2.0 * np.pi * np.outer(np.arange(n_t), bins) / n_t
    n_bins = len(bins)
    bands = np.array_split(np.arange(n_bins), 3) if n_bins >= 3 else [np.arange(n_bins)] * 3
    indicator = np.zeros((n_bins, 3))
    for b, idx in enumerate(bands):
        indicator[idx, b] = 1.0
    return np.cos(angle), np.sin(angle), indicator


class HandGraphFeatures(FeatureFamily):
    """The 14 hand-designed features per pad of ``trainer.baseline``, with ONNX nodes."""

    def __init__(self, pad_sizes=None, pad_shapes=None):
        self.pad_sizes = pad_sizes
        self.pad_shapes = pad_shapes

    def _fit(self, X, y) -> None:
        self.n_features_out_ = len(FEATURES_PER_PAD) * len(self.shapes_)

    def _transform(self, X: np.ndarray) -> np.ndarray:
        return np.concatenate([pad_features(X[:, a:b], rows, cols)
                               for (a, b), (rows, cols) in zip(pad_bounds(self.shapes_), self.shapes_, strict=True)],
                              axis=1)

    def error_bounds(self, X) -> np.ndarray:
        """A float32 bound per feature (``pad_error_bounds``), pad by pad."""
        X = self._check(X)
        return np.concatenate([pad_error_bounds(X[:, a:b], rows, cols)
                               for (a, b), (rows, cols) in zip(pad_bounds(self.shapes_), self.shapes_, strict=True)],
                              axis=1)

    def onnx_nodes(self, g, frames: str) -> str:
        n_t = int(self.n_timepoints_)
        parts = [self._pad_nodes(g, slice_nodes(g, frames, a, b, 2, "pad"), rows, cols, n_t)
                 for (a, b), (rows, cols) in zip(pad_bounds(self.shapes_), self.shapes_, strict=True)]
        return g.op("Concat", parts, "hand_features", axis=1) if len(parts) > 1 else parts[0]

    @staticmethod
    def _pad_nodes(g, P: str, rows: int, cols: int, n_t: int) -> str:
        """One pad ``[N, T, rows*cols]`` -> ``[N, 14]``."""
        size = rows * cols
        total_n = size * n_t
        flat = g.op("Reshape", [P, g.const("flat", [0, total_n], np.int64)], "pad_flat")
        peak = g.op("ReduceMax", [flat], "max", axes=[1], keepdims=1)
        mean = g.op("ReduceMean", [flat], "mean", axes=[1], keepdims=1)
        dev = g.op("Sub", [flat, mean], "dev")
        std = g.op("Sqrt", [g.op("ReduceMean", [g.op("Mul", [dev, dev])], "var", axes=[1], keepdims=1)], "std")
        k = total_n // 2 + 1
        top = g.name("top")
        g.op("TopK", [flat, g.const("k", [k], np.int64)], outputs=[top, g.name("top_idx")], axis=1, largest=1)
        middle = slice_nodes(g, top, k - 2 if total_n % 2 == 0 else k - 1, k, 1, "middle")
        median = g.op("ReduceMean", [middle], "median", axes=[1], keepdims=1)
        signal = g.op("ReduceMean", [P], "signal", axes=[2], keepdims=0)  # [N, T]
        centred = g.op("Sub", [signal, g.op("ReduceMean", [signal], "signal_mean", axes=[1], keepdims=1)], "sig_c")
        cos, sin, bands = dft_matrices(n_t)
        re = g.op("MatMul", [centred, g.const("dft_cos", cos)], "re")
        im = g.op("MatMul", [centred, g.const("dft_sin", sin)], "im")
        power = g.op("Add", [g.op("Mul", [re, re]), g.op("Mul", [im, im])], "power")
        energy = g.op("MatMul", [power, g.const("ones", np.ones((cos.shape[1], 1)))], "energy")  # [N, 1]
        shares = g.op("Div", [g.op("MatMul", [power, g.const("bands", bands)], "band_energy"),
                              g.op("Max", [energy, g.const("tiny", 1e-12)], "energy_floor")], "shares")
        log_energy = g.op("Log", [g.op("Add", [energy, g.const("one", 1.0)])], "log_energy")
        first, last = slice_nodes(g, signal, 0, 1, 1, "sig_first"), slice_nodes(g, signal, n_t - 1, n_t, 1, "sig_last")
        deriv = g.op("Mul", [g.op("Sub", [last, first]), g.const("inv_steps", 1.0 / max(n_t - 1, 1))], "mean_deriv")
        cop = HandGraphFeatures._cop_nodes(g, P, rows, cols, n_t)
        return g.op("Concat", [peak, mean, median, std, shares, log_energy, deriv, cop], "pad_hand", axis=1)

    @staticmethod
    def _cop_nodes(g, P: str, rows: int, cols: int, n_t: int) -> str:
        """Centre of pressure mean (x, y), net displacement (dx, dy), mean speed: ``[N, 5]``."""
        ys, xs = np.divmod(np.arange(rows * cols), cols)
        weight = g.op("ReduceSum", [P, g.const("axis2", [2], np.int64)], "weight", keepdims=1)  # [N, T, 1]
        pressed = g.op("Greater", [weight, g.const("zero", 0.0)], "pressed")
        safe = g.op("Where", [pressed, weight, g.const("one", 1.0)], "safe_weight")
        moments = g.op("Div", [g.op("MatMul", [P, g.const("xy", np.stack([xs, ys], axis=1))], "moments"), safe],
                       "cop_raw")  # [N, T, 2]
        cop = g.op("Where", [pressed, moments, g.const("centre", [(cols - 1) / 2, (rows - 1) / 2])], "cop")
        mean = g.op("ReduceMean", [cop], "cop_mean", axes=[1], keepdims=0)
        shift = g.op("Sub", [slice_nodes(g, cop, n_t - 1, n_t, 1, "cop_last"), slice_nodes(g, cop, 0, 1, 1, "cop_0")])
        net = g.op("Reshape", [shift, g.const("two", [0, 2], np.int64)], "cop_net")
        step = g.op("Sub", [slice_nodes(g, cop, 1, n_t, 1, "cop_next"), slice_nodes(g, cop, 0, n_t - 1, 1, "cop_prev")])
        sq = g.op("ReduceSum", [g.op("Mul", [step, step]), g.const("axis2", [2], np.int64)], "step_sq", keepdims=0)
        speed = g.op("ReduceMean", [g.op("Sqrt", [sq], "step_len")], "speed", axes=[1], keepdims=1)
        return g.op("Concat", [mean, net, speed], "cop_features", axis=1)


def pad_error_bounds(P: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """Bound ``(n, 14)`` on |float32 graph - float64| of one pad's features ``P`` ``(n, S, T)``.

    Each feature's rounding follows the graph's own sums (``trainer.numerics``: a float32 sum of m
    terms is within ``gamma(m) * sum |terms|``): the whole-pad mean and spread carry gamma(S T);
    the mean-pressure signal only gamma(S) per frame, so the FFT features, the mean derivative and
    the centre of pressure (a ratio of two pad sums: scale-free) are bounded at the size of their
    own values, not of the pad's largest taxel. Only genuinely ill-conditioned features get their
    whole range: FFT shares of a signal whose energy is within ``SAFETY`` x its error of zero, the
    centre of pressure of a frame whose summed pressure is within ``SAFETY`` x its error of zero
    (only possible with negative input).
    """
    P = np.asarray(P, dtype=np.float64)
    n, size, n_t = P.shape
    f = pad_features(P, rows, cols)
    count = size * n_t
    e_mean = gamma(count + 2) * np.abs(P).mean(axis=(1, 2))
    std = f[:, 3]
    e_var = gamma(count + 6) * (std + e_mean) ** 2 + e_mean**2
    e_std = np.where(std > 0, np.minimum(np.sqrt(e_var), e_var / np.maximum(std, 1e-300)), np.sqrt(e_var)) + U32 * std

    signal = P.mean(axis=1)  # (n, T)
    e_sig = gamma(size + 2) * np.abs(P).mean(axis=1).max(axis=1)
    centred = signal - signal.mean(axis=1, keepdims=True)
    e_c = 2 * e_sig + gamma(n_t + 2) * np.abs(signal).mean(axis=1) + U32 * np.abs(centred).max(axis=1)
    spectrum = np.fft.rfft(centred, axis=1)[:, 1:]
    e_ri = n_t * e_c + gamma(n_t + 2) * np.abs(centred).sum(axis=1)  # one DFT bin, real or imaginary part
    power = np.abs(spectrum) ** 2
    e_power = (2 * (np.abs(spectrum.real) + np.abs(spectrum.imag)) * e_ri[:, None] + 2 * e_ri[:, None] ** 2
               + gamma(3) * power)
    energy = power.sum(axis=1)
    e_energy = e_power.sum(axis=1) + gamma(power.shape[1] + 1) * energy
    conditioned = energy > SAFETY * e_energy
    shares = f[:, 4:7]
    exact = e_energy == 0  # an all-zero pad: every sum is exact, the shares are 0 in both
    share_err = np.where(exact[:, None], 0.0, np.where(conditioned[:, None],
                         (1 + shares) * (e_energy / np.where(conditioned, energy - e_energy, 1.0))[:, None] + U32,
                         1.0))
    e_log = e_energy / (1 + np.maximum(energy - e_energy, 0)) + U32 * (1 + np.abs(f[:, 7]))
    e_deriv = 2 * e_sig / max(n_t - 1, 1) + gamma(3) * np.abs(f[:, 8])

    e_cop = _cop_frame_error(P, rows, cols)  # (n,) worst frame, taxel units
    cop_mean_err = e_cop[:, None] + gamma(n_t + 1) * np.abs(f[:, 9:11])
    net_err = 2 * e_cop[:, None] + U32 * np.abs(f[:, 11:13])
    ys, xs = np.divmod(np.arange(size), cols)
    weight = P.sum(axis=1)
    safe = np.where(weight > 0, weight, 1.0)
    cop = np.stack([np.where(weight > 0, np.einsum("nct,c->nt", P, v) / safe, (m - 1) / 2)
                    for v, m in ((xs, cols), (ys, rows))], axis=-1)  # (n, T, 2)
    step = np.linalg.norm(np.diff(cop, axis=1), axis=2).max(axis=1) if n_t > 1 else np.zeros(n)
    speed_err = 2 * np.sqrt(2) * e_cop + gamma(n_t + 5) * (np.abs(f[:, 13]) + step)
    return np.column_stack([U32 * np.abs(f[:, 0]), e_mean, U32 * np.abs(f[:, 2]), e_std, share_err, e_log,
                            e_deriv, cop_mean_err, net_err, speed_err])


def _cop_frame_error(P: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """Worst frame's bound on the float32 centre of pressure (taxel units), ``(n,)``: the moment and
    the weight are pad sums, the quotient's error is (e_moment + |cop| e_weight) / (|w| - e_weight).
    An empty frame (all zero) is the centre in both; a weight within SAFETY x its error of zero
    (negative input only) may switch the Where: the whole pad range."""
    size = rows * cols
    ys, xs = np.divmod(np.arange(size), cols)
    absum = np.abs(P).sum(axis=1)  # (n, T)
    weight = P.sum(axis=1)
    e_w = gamma(size + 2) * absum
    e_m = gamma(size + 3) * absum * float(max(rows, cols) - 1)
    cop = np.maximum(np.abs(np.einsum("nct,c->nt", P, xs)), np.abs(np.einsum("nct,c->nt", P, ys))) / np.where(
        weight != 0, np.abs(weight), 1.0)
    ill = (np.abs(weight) <= SAFETY * e_w) & (absum > 0)
    den = np.where(ill | (absum == 0), 1.0, np.abs(weight) - e_w)
    err = np.where(absum == 0, 0.0, (e_m + cop * e_w) / den + U32 * cop)
    return np.where(ill.any(axis=1), float(rows + cols), err.max(axis=1))
