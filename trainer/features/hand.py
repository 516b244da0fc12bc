"""The paper's hand-designed baseline features (``trainer.baseline.pad_features``: 14 per pad) as
ONNX nodes, so the baseline ships as one graph like every other family.

Per pad: max, standard deviation and an exact median (TopK of the largest half) of all taxel values;
the rest from the mean-pressure signal and centre of pressure over time (``trainer.features.pad_series``,
shared with the level statistics; the FFT is a DFT MatMul).
"""

from __future__ import annotations

import numpy as np

from trainer.baseline import FEATURES_PER_PAD, pad_features
from trainer.features.base import FeatureFamily, OnnxParts, pad_bounds
from trainer.features.pad_batch import PadBatch, median_nodes, peak_nodes
from trainer.features.pad_series import SeriesColumns, SeriesNeed, pad_series_nodes
from trainer.numerics import SAFETY, U32, gamma

__all__ = ["HandGraphFeatures", "pad_error_bounds"]


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

    def onnx_parts(self, g, frames: str) -> OnnxParts:
        """All pads at once (``trainer.features.pad_batch``, ``trainer.features.pad_series``): the series'
        rows over time, then peak, median, std of the pads; ``_pad_major_order`` says where each
        feature of the reference's pad-major order sits (the std is multiplied by ``_std_nodes``' factor)."""
        n_t, n_pads = int(self.n_timepoints_), len(self.shapes_)
        batch = PadBatch.of(self.shapes_)
        padded = batch.nodes(g, frames)  # [N, G, S, T]
        peak = peak_nodes(g, padded)  # [N, G]
        median = median_nodes(g, batch, padded, peak, n_t)  # [N, G]
        series = pad_series_nodes(g, frames, self.shapes_, n_t, SeriesNeed(hand=True, fullscale=None))
        std, std_scale = _std_nodes(g, batch, padded, series.signal_mean, n_t)
        n_rows = n_pads * len(series.columns.series) * series.columns.width
        columns = _pad_major_order(series.columns, n_pads, n_rows)
        scales = np.ones(len(columns))
        scales[3 :: len(FEATURES_PER_PAD)] = std_scale  # the std's factor; every other feature is as computed
        return OnnxParts([series.flat, peak, median, std], np.asarray(columns), n_rows + 3 * n_pads, scales,
                         (n_rows, n_pads, n_pads, n_pads))


_FROM_SERIES = [("signal", "mean"), ("signal", "share1"), ("signal", "share2"), ("signal", "share3"),
                ("signal", "log_energy"), ("signal", "mean_derivative"), ("cop_x", "mean"), ("cop_y", "mean"),
                ("cop_x", "change"), ("cop_y", "change"), ("signal", "speed")]
"""``FEATURES_PER_PAD`` 1 and 4 .. 13 as (series, quantity) of ``trainer.features.pad_series``."""


def _pad_major_order(columns: SeriesColumns, n_pads: int, n_rows: int) -> list[int]:
    """Where each feature of ``FEATURES_PER_PAD``, pad by pad, sits in the parts (the series' rows,
    ``n_rows`` columns, then ``[peak, median, std]`` of the pads)."""
    order = []
    for p in range(n_pads):
        rows = [columns.column(p, series, quantity) for series, quantity in _FROM_SERIES]
        order += [n_rows + p, rows[0], n_rows + n_pads + p, n_rows + 2 * n_pads + p, *rows[1:]]
    return order


def _std_nodes(g, batch: PadBatch, padded: str, mean: str, n_t: int) -> tuple[str, np.ndarray]:
    """Standard deviation of each pad's values ``[N, G]`` about ``mean`` ``[N, G, 1, 1]`` (two passes),
    times the returned factor per pad."""
    dev = g.op("Sub", [padded, mean], "dev")
    if not batch.padded:  # the root of the sum of squares: the std times sqrt(size T)
        return g.op("ReduceL2", [dev], "std_root", axes=[2, 3], keepdims=0), np.sqrt(batch.sizes * float(n_t))
    # padded pads: each slot's squares over time [N, G, S], then a weighted sum over the slots whose
    # weights are 0 on padding and 1 / (size T) on the pad's taxels (a pass over T times fewer values
    # than the whole tensor, and no subtraction that could cancel)
    slot_sq = g.op("ReduceSumSquare", [dev], "slot_sq", axes=[3], keepdims=0)
    weighted = g.op("Mul", [slot_sq, g.const("std_weights", batch.mask / (batch.sizes[:, None] * n_t))], "slot_var")
    var = g.op("ReduceSum", [weighted, g.const("slot_axis", [2], np.int64)], "var", keepdims=0)
    return g.op("Sqrt", [var], "std"), np.ones(len(batch.sizes))


def pad_error_bounds(P: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """Bound ``(n, 14)`` on |float32 graph - float64| of one pad's features ``P`` ``(n, S, T)``.

    Each feature's rounding follows the graph's own sums (``trainer.numerics``), so features of the
    mean-pressure signal are bounded at the size of their own values, not of the pad's largest taxel.
    Only ill-conditioned features (energy or summed pressure within ``SAFETY`` x its error of zero) get
    their whole range.
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
