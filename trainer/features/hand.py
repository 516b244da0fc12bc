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
from trainer.features.base import FeatureFamily, OnnxParts, pad_bounds
from trainer.features.pad_batch import PadBatch, median_nodes, peak_nodes
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

    def onnx_parts(self, g, frames: str) -> OnnxParts:
        """All pads at once (``trainer.features.pad_batch``): the features come out feature-major
        (``_time_nodes``' rows, then peak, median, std), and ``_pad_major_order`` says where each one
        of the reference's pad-major order sits and what it is multiplied by there."""
        n_t, n_pads = int(self.n_timepoints_), len(self.shapes_)
        batch = PadBatch.of(self.shapes_)
        padded = batch.nodes(g, frames)  # [N, G, S, T]
        peak = peak_nodes(g, padded)  # [N, G]
        median = median_nodes(g, batch, frames, padded, peak, n_t)  # [N, G]
        rows, signal_mean = _time_nodes(g, batch, padded, self.shapes_, n_t)  # [N, G, 3, width], [N, G, 1, 1]
        std, std_scale = _std_nodes(g, batch, padded, signal_mean, n_t)
        flat = g.op("Reshape", [rows, g.const("flat", [0, -1], np.int64)], "time_flat")
        columns, scales = _pad_major_order(n_pads, n_t)
        scales[3 :: len(FEATURES_PER_PAD)] = std_scale
        return OnnxParts([flat, peak, median, std], np.asarray(columns), (_row_width(n_t) * 3 + 3) * n_pads, scales)


def _row_width(n_t: int) -> int:
    """Columns of ``_time_nodes``' rows of one series: mean, 3 band shares, log energy, ``time_rows``'
    products, mean speed."""
    return 1 + 3 + 1 + time_rows(n_t)[0].shape[0] + 1


def _pad_major_order(n_pads: int, n_t: int) -> tuple[list[int], np.ndarray]:
    """Where each feature of ``FEATURES_PER_PAD``, pad by pad, sits in the parts: ``_time_nodes``' rows
    flattened (pad by pad, 3 series - signal, centre of pressure x and y - by ``_row_width``), then
    ``[peak, median, std]`` of the pads; and the factor each carries there (1; the std's is set by
    the caller)."""
    width = _row_width(n_t)
    by_pad = width * 3 * n_pads
    deriv = width - 3  # time_rows' last two products (mean derivative, last - first), then the speed
    order = []
    for p in range(n_pads):
        signal, cop_x, cop_y = (width * (3 * p + k) for k in range(3))
        order += [by_pad + p, signal, by_pad + n_pads + p, by_pad + 2 * n_pads + p, signal + 1, signal + 2,
                  signal + 3, signal + 4, signal + deriv, cop_x, cop_y, cop_x + deriv + 1, cop_y + deriv + 1,
                  signal + width - 1]
    return order, np.ones(len(order))


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


def time_rows(n_t: int) -> tuple[np.ndarray, int]:
    """``[2B + T-1 + 2, T]`` over the frames: cosine and sine of rfft bins 1 .. T//2 and the T-1 steps
    (the values whose squares count), then the mean derivative and last - first; and B. Applied to
    the centred series (two passes: a constant series has exactly zero energy, not float32 noise
    whose band shares are anything)."""
    cos, sin, _ = dft_matrices(n_t)
    rise = np.zeros((1, n_t))
    rise[0, 0], rise[0, -1] = -1.0, 1.0
    steps = np.eye(n_t - 1, n_t, 1) - np.eye(n_t - 1, n_t)
    return np.concatenate([cos.T, sin.T, steps, rise / max(n_t - 1, 1), rise]), cos.shape[1]


def _time_nodes(g, batch: PadBatch, padded: str, shapes, n_t: int) -> tuple[str, str]:
    """Everything from the per-frame pad means and centres of pressure, for all pads at once, as rows
    ``[N, G, 3, _row_width]`` of each pad's three series (signal, centre x, centre y): mean, FFT band
    shares / 2 and log energy, mean derivative, last - first (the centre's net displacement), mean
    speed (on the signal). Also the pads' mean value ``[N, G, 1, 1]``. Columns a series does not use
    are computed and ignored (cheaper than slicing them away: onnxruntime pays per node). Time stays
    the last axis throughout, so each product over time is one GEMM for all pads."""
    n_pads, width = len(shapes), int(batch.sizes.max())
    kinds = np.zeros((n_pads, 3, width))  # per pad: 1, x, y of each taxel slot over the pad's size (0 on padding)
    centre = np.zeros((n_pads, 2, 1))
    for p, (rows, cols) in enumerate(shapes):
        y, x = np.divmod(np.arange(rows * cols), cols)
        kinds[p, :, : rows * cols] = np.stack([np.ones(rows * cols), x, y]) / (rows * cols)
        centre[p, :, 0] = (cols - 1) / 2, (rows - 1) / 2
    moments = g.op("MatMul", [g.const("pad_moments", kinds), padded], "moments")  # [N, G, 3, T]
    signal, mxy = g.name("signal"), g.name("mxy")
    g.op("Split", [moments, g.const("split", [1, 2], np.int64)], outputs=[signal, mxy], axis=2)
    pressed = g.op("Greater", [signal, g.const("zero", 0.0)], "pressed")
    # an unpressed pad's quotient (0/0, x/negative) is computed and never selected: no guard needed
    cop = g.op("Where", [pressed, g.op("Div", [mxy, signal], "cop_raw"), g.const("centre", centre)], "cop")
    series = g.op("Concat", [signal, cop], "series", axis=2)  # [N, G, 3, T]
    mean = g.op("ReduceMean", [series], "series_mean", axes=[3], keepdims=1)  # [N, G, 3, 1]
    centred = g.op("Sub", [series, mean], "centred")
    rows_t, n_bins = time_rows(n_t)
    over_time = g.op("MatMul", [centred, g.const("time_rows", rows_t.T)], "over_time")  # [N, G, 3, 2B + T-1 + 2]
    sq = g.op("Mul", [over_time, over_time], "power")  # re^2 and im^2 of each bin, the steps' squares (and 2 unused)
    _, _, bands = dft_matrices(n_t)
    energy_cols = np.zeros((rows_t.shape[0], 4))  # [band energies, energy] from the bins' squares
    energy_cols[: 2 * n_bins] = np.concatenate([np.concatenate([bands, bands]), np.ones((2 * n_bins, 1))], axis=1)
    energy4 = g.op("MatMul", [sq, g.const("band_rows", energy_cols)], "energy4")  # [N, G, 3, 4]
    band_energy, energy = g.name("band_energy"), g.name("energy")
    g.op("Split", [energy4, g.const("split_energy", [3, 1], np.int64)], outputs=[band_energy, energy], axis=3)
    # floored like the reference: a constant series whose float32 mean is an ulp off its values has an
    # energy of float32 noise, and unfloored shares of that noise would be anything
    shares = g.op("Div", [band_energy, g.op("Max", [energy, g.const("tiny", 1e-12)], "energy_floor")], "shares")
    log_energy = g.op("Log", [g.op("Add", [energy, g.const("one", 1.0)])], "log_energy")
    pair = np.zeros((3, 3))  # dx^2 + dy^2 into the signal's row
    pair[0, 1] = pair[0, 2] = 1.0
    step_len = g.op("Sqrt", [g.op("MatMul", [g.const("dx2_dy2", pair), sq], "step_len2")], "step_len")
    step_mean = np.zeros((rows_t.shape[0], 1))  # the mean over the steps' columns
    step_mean[2 * n_bins : 2 * n_bins + n_t - 1] = 1.0 / max(n_t - 1, 1)
    speed = g.op("MatMul", [step_len, g.const("step_mean", step_mean)], "speed")  # [N, G, 3, 1]
    rows = g.op("Concat", [mean, shares, log_energy, over_time, speed], "time_rows", axis=3)
    signal_mean = g.op("Slice", [mean, g.const("start", [0], np.int64), g.const("stop", [1], np.int64),
                                 g.const("axis", [2], np.int64)], "signal_mean")
    return rows, signal_mean


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
