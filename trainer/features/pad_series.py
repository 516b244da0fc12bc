"""Per-pad series over time and what both the hand-designed and the level-statistics features take
from them, built once per graph for every pad at once.

Why one pipeline: onnxruntime pays per node, not per row, so seven series through one chain of nodes
cost what three did. The series (rows of ``[N, G, K, T]``): the hand family's mean value and centre of
pressure, the stats family's pressure, contact area and centroid. Per series over time: mean, root sum
of squares about it, FFT band shares, log energy, ``time_rows``' products and the centre's mean speed;
columns a series does not use are computed and ignored (cheaper than slicing them away).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from trainer.features.pad_batch import PadBatch, magnitude_nodes
from trainer.features.signals import CONTACT_FRACTION

__all__ = ["STATS_SERIES", "SeriesColumns", "SeriesNeed", "dft_matrices", "pad_series_nodes"]

HAND_SERIES = ("signal", "cop_x", "cop_y")
STATS_SERIES = ("pressure", "area", "cx", "cy")
"""Rows of each family (``trainer.features.signals.SIGNALS`` order)."""


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


def time_rows(n_t: int) -> tuple[np.ndarray, int]:
    """``[2B + T-1 + 2, T]`` over the frames: cosine and sine of rfft bins 1 .. T//2 and the T-1 steps
    (the values whose squares count), then the mean derivative and last - first; and B. Applied to
    the centred series (two passes)."""
    cos, sin, _ = dft_matrices(n_t)
    rise = np.zeros((1, n_t))
    rise[0, 0], rise[0, -1] = -1.0, 1.0
    steps = np.eye(n_t - 1, n_t, 1) - np.eye(n_t - 1, n_t)
    return np.concatenate([cos.T, sin.T, steps, rise / max(n_t - 1, 1), rise]), cos.shape[1]


@dataclass(frozen=True)
class SeriesColumns:
    """Where each quantity of each series sits in the flattened rows ``[N, G * K * width]``."""

    series: tuple[str, ...]
    n_t: int

    @property
    def spectral(self) -> bool:
        """Whether the rows hold the spectral columns (only the hand family reads them)."""
        return "signal" in self.series

    @cached_property
    def n_products(self) -> int:
        """How many of ``time_rows``' products the spectral rows hold."""
        return time_rows(self.n_t)[0].shape[0]

    @property
    def width(self) -> int:
        return 7 + self.n_products if self.spectral else 3

    def column(self, pad: int, series: str, quantity: str) -> int:
        if self.spectral:
            products, n_products = 6, self.n_products  # where time_rows' products start, how many
            at = {"mean": 0, "root_sq": 1, "share1": 2, "share2": 3, "share3": 4, "log_energy": 5,
                  "mean_derivative": products + n_products - 2, "change": products + n_products - 1,
                  "speed": products + n_products}[quantity]
        else:
            at = {"mean": 0, "root_sq": 1, "change": 2}[quantity]
        return (pad * len(self.series) + self.series.index(series)) * self.width + at


@dataclass(frozen=True)
class PadSeries:
    """The built nodes: ``flat`` ``[N, G * K * width]`` (``columns`` says where), and the pads' mean
    value ``[N, G, 1, 1]`` (the hand family's std; None without the hand series)."""

    flat: str
    columns: SeriesColumns
    signal_mean: str | None


@dataclass(frozen=True)
class SeriesNeed:
    """Which series a graph needs: the hand's, and the stats' (with their full scale) or not."""

    hand: bool
    fullscale: float | None


def pad_series_nodes(g, frames: str, shapes: Sequence[tuple[int, int]], n_t: int, need: SeriesNeed) -> PadSeries:
    """The series and their rows over time, built once per graph with the first call's ``need``
    (``trainer.feature_svc.FeatureSVC.onnx_features`` calls first, with every family's)."""
    return g.shared(("pad_series", frames), lambda: _build(g, frames, shapes, n_t, need))


def _build(g, frames: str, shapes, n_t: int, need: SeriesNeed) -> PadSeries:
    batch = PadBatch.of(shapes)
    padded = batch.nodes(g, frames)  # [N, G, S, T]
    parts, names = [], ()
    if need.hand:
        parts += _hand_series(g, padded, shapes, int(batch.sizes.max()))
        names += HAND_SERIES
    if need.fullscale is not None:
        parts += _stats_series(g, padded, shapes, int(batch.sizes.max()), need.fullscale)
        names += STATS_SERIES
    series = g.op("Concat", parts, "series", axis=2) if len(parts) > 1 else parts[0]  # [N, G, K, T]
    rows, mean = _time_nodes(g, series, names, n_t)
    columns = SeriesColumns(names, n_t)
    flat = g.op("Reshape", [rows, g.const("flat", [0, -1], np.int64)], "series_flat")
    signal_mean = None
    if need.hand:
        signal_mean = g.op("Slice", [mean, g.const("start", [0], np.int64), g.const("stop", [1], np.int64),
                                     g.const("axis", [2], np.int64)], "signal_mean")
    return PadSeries(flat, columns, signal_mean)


def _hand_series(g, padded: str, shapes, width: int) -> list[str]:
    """``[signal, centre]`` ``[N, G, 1, T]``, ``[N, G, 2, T]`` from one MatMul (weights 1, x, y over the
    pad's size: the quotient is the reference's, the signal needs no Mul)."""
    kinds = np.zeros((len(shapes), 3, width))  # 0 on padding slots
    centre = np.zeros((len(shapes), 2, 1))
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
    return [signal, cop]


def _stats_series(g, padded: str, shapes, width: int, fullscale: float) -> list[str]:
    """``trainer.features.signals.pad_signals`` of the padded pads: ``[pressure, area, centroid]``
    ``[N, G, 1|1|2, T]``. Weights over the pad's size and full scale, so the pressure needs no Mul and
    the centroid's denominator ``(sum |x| + fullscale) / (size fullscale)`` is the pressure plus a constant."""
    weights = np.zeros((len(shapes), 3, width))
    area = np.zeros((len(shapes), 1, width))
    inv_size = np.zeros((len(shapes), 1, 1))
    for p, (rows, cols) in enumerate(shapes):
        size = rows * cols
        y, x = np.divmod(np.arange(size), cols)
        weights[p, :, :size] = np.stack([np.ones(size), (x - (cols - 1) / 2.0) / cols,
                                         (y - (rows - 1) / 2.0) / rows]) / (size * fullscale)
        area[p, 0, :size] = 1.0 / size
        inv_size[p] = 1.0 / size
    mag = magnitude_nodes(g, padded)  # taxels are non-negative on the wire; |x| for stress input
    moments = g.op("MatMul", [g.const("stats_moments", weights), mag], "stats_moments")  # [N, G, 3, T]
    pressure, mxy = g.name("pressure"), g.name("stats_mxy")
    g.op("Split", [moments, g.const("split", [1, 2], np.int64)], outputs=[pressure, mxy], axis=2)
    den = g.op("Add", [pressure, g.const("inv_size", inv_size)], "centroid_den")
    contact = g.op("Cast", [g.op("GreaterOrEqual", [padded, g.const("contact_level", CONTACT_FRACTION * fullscale)])],
                   "contact", to=1)
    touched = g.op("MatMul", [g.const("area_weights", area), contact], "area")  # [N, G, 1, T]
    return [pressure, touched, g.op("Div", [mxy, den], "centroid")]


def _time_nodes(g, series: str, names: tuple[str, ...], n_t: int) -> tuple[str, str]:
    """Rows ``[N, G, K, width]`` of every series over time (module docstring) and their means
    ``[N, G, K, 1]``. Time stays the last axis throughout, so each product over time is one GEMM."""
    mean = g.op("ReduceMean", [series], "series_mean", axes=[3], keepdims=1)  # [N, G, K, 1]
    centred = g.op("Sub", [series, mean], "centred")  # two passes
    # the stats' std (the hand's rows have the mean in its place)
    root_sq = g.op("ReduceL2", [centred], "root_sq", axes=[3], keepdims=1) if "pressure" in names else mean
    if "signal" not in names:  # the stats alone: mean, std, last - first
        rise = np.zeros((n_t, 1))
        rise[0, 0], rise[-1, 0] = -1.0, 1.0
        change = g.op("MatMul", [centred, g.const("rise", rise)], "change")
        return g.op("Concat", [mean, root_sq, change], "time_rows", axis=3), mean
    rows_t, n_bins = time_rows(n_t)
    over_time = g.op("MatMul", [centred, g.const("time_rows", rows_t.T)], "over_time")  # [N, G, K, 2B + T-1 + 2]
    sq = g.op("Mul", [over_time, over_time], "power")  # re^2 and im^2 of each bin, the steps' squares (and 2 unused)
    _, _, bands = dft_matrices(n_t)
    energy_cols = np.zeros((rows_t.shape[0], 4))  # [band energies, energy] from the bins' squares
    energy_cols[: 2 * n_bins] = np.concatenate([np.concatenate([bands, bands]), np.ones((2 * n_bins, 1))], axis=1)
    energy4 = g.op("MatMul", [sq, g.const("band_rows", energy_cols)], "energy4")  # [N, G, K, 4]
    band_energy, energy = g.name("band_energy"), g.name("energy")
    g.op("Split", [energy4, g.const("split_energy", [3, 1], np.int64)], outputs=[band_energy, energy], axis=3)
    # floored like the reference: a constant series whose float32 mean is an ulp off its values has an
    # energy of float32 noise, and unfloored shares of that noise would be anything
    shares = g.op("Div", [band_energy, g.op("Max", [energy, g.const("tiny", 1e-12)], "energy_floor")], "shares")
    log_energy = g.op("Log", [g.op("Add", [energy, g.const("one", 1.0)])], "log_energy")
    pair = np.zeros((len(names), len(names)))  # dx^2 + dy^2 into the signal's row
    pair[names.index("signal"), [names.index("cop_x"), names.index("cop_y")]] = 1.0
    step_len = g.op("Sqrt", [g.op("MatMul", [g.const("dx2_dy2", pair), sq], "step_len2")], "step_len")
    step_mean = np.zeros((rows_t.shape[0], 1))  # the mean over the steps' columns
    step_mean[2 * n_bins : 2 * n_bins + n_t - 1] = 1.0 / max(n_t - 1, 1)
    speed = g.op("MatMul", [step_len, g.const("step_mean", step_mean)], "speed")  # [N, G, K, 1]
    return g.op("Concat", [mean, root_sq, shares, log_energy, over_time, speed], "time_rows", axis=3), mean
