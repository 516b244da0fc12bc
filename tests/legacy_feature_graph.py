"""The hand-designed and level-statistics graphs as exported before issue #16 (one chain of nodes
per pad), frozen here so a test can pin the batched graph's decisions and scores to them."""

from __future__ import annotations

import numpy as np

from trainer.features.base import pad_bounds
from trainer.features.pad_series import dft_matrices


def slice_nodes(g, tensor: str, start: int, stop: int, axis: int, hint: str) -> str:
    """``tensor[..., start:stop, ...]`` along ``axis`` (a Slice, not a Gather)."""
    return g.op("Slice", [tensor, g.const("start", [start], np.int64), g.const("stop", [stop], np.int64),
                          g.const("axis", [axis], np.int64)], hint)


def legacy_hand_nodes(family, g, frames: str) -> str:
    n_t = int(family.n_timepoints_)
    parts = [_pad_nodes(g, slice_nodes(g, frames, a, b, 2, "pad"), rows, cols, n_t)
             for (a, b), (rows, cols) in zip(pad_bounds(family.shapes_), family.shapes_, strict=True)]
    return g.op("Concat", parts, "hand_features", axis=1) if len(parts) > 1 else parts[0]


def _pad_nodes(g, P: str, rows: int, cols: int, n_t: int) -> str:
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
    signal = g.op("ReduceMean", [P], "signal", axes=[2], keepdims=0)
    centred = g.op("Sub", [signal, g.op("ReduceMean", [signal], "signal_mean", axes=[1], keepdims=1)], "sig_c")
    cos, sin, bands = dft_matrices(n_t)
    re = g.op("MatMul", [centred, g.const("dft_cos", cos)], "re")
    im = g.op("MatMul", [centred, g.const("dft_sin", sin)], "im")
    power = g.op("Add", [g.op("Mul", [re, re]), g.op("Mul", [im, im])], "power")
    energy = g.op("MatMul", [power, g.const("ones", np.ones((cos.shape[1], 1)))], "energy")
    shares = g.op("Div", [g.op("MatMul", [power, g.const("bands", bands)], "band_energy"),
                          g.op("Max", [energy, g.const("tiny", 1e-12)], "energy_floor")], "shares")
    log_energy = g.op("Log", [g.op("Add", [energy, g.const("one", 1.0)])], "log_energy")
    first, last = slice_nodes(g, signal, 0, 1, 1, "sig_first"), slice_nodes(g, signal, n_t - 1, n_t, 1, "sig_last")
    deriv = g.op("Mul", [g.op("Sub", [last, first]), g.const("inv_steps", 1.0 / max(n_t - 1, 1))], "mean_deriv")
    cop = _cop_nodes(g, P, rows, cols, n_t)
    return g.op("Concat", [peak, mean, median, std, shares, log_energy, deriv, cop], "pad_hand", axis=1)


def _cop_nodes(g, P: str, rows: int, cols: int, n_t: int) -> str:
    ys, xs = np.divmod(np.arange(rows * cols), cols)
    weight = g.op("ReduceSum", [P, g.const("axis2", [2], np.int64)], "weight", keepdims=1)
    pressed = g.op("Greater", [weight, g.const("zero", 0.0)], "pressed")
    safe = g.op("Where", [pressed, weight, g.const("one", 1.0)], "safe_weight")
    moments = g.op("Div", [g.op("MatMul", [P, g.const("xy", np.stack([xs, ys], axis=1))], "moments"), safe], "cop_raw")
    cop = g.op("Where", [pressed, moments, g.const("centre", [(cols - 1) / 2, (rows - 1) / 2])], "cop")
    mean = g.op("ReduceMean", [cop], "cop_mean", axes=[1], keepdims=0)
    shift = g.op("Sub", [slice_nodes(g, cop, n_t - 1, n_t, 1, "cop_last"), slice_nodes(g, cop, 0, 1, 1, "cop_0")])
    net = g.op("Reshape", [shift, g.const("two", [0, 2], np.int64)], "cop_net")
    step = g.op("Sub", [slice_nodes(g, cop, 1, n_t, 1, "cop_next"), slice_nodes(g, cop, 0, n_t - 1, 1, "cop_prev")])
    sq = g.op("ReduceSum", [g.op("Mul", [step, step]), g.const("axis2", [2], np.int64)], "step_sq", keepdims=0)
    speed = g.op("ReduceMean", [g.op("Sqrt", [sq], "step_len")], "speed", axes=[1], keepdims=1)
    return g.op("Concat", [mean, net, speed], "cop_features", axis=1)


def legacy_stats_peak(family, g, frames: str) -> str:
    """The level statistics' per-pad peak as before: one Slice + ReduceMax per pad (unscaled, as the
    current layout holds it: its scale is in the SVM's weights)."""
    over_time = g.op("ReduceMax", [frames], "taxel_peak", axes=[1], keepdims=0)
    peaks = [g.op("ReduceMax", [slice_nodes(g, over_time, a, b, 1, "pad_taxels")], "pad_peak", axes=[1], keepdims=1)
             for a, b in pad_bounds(family.shapes_)]
    return g.op("Concat", peaks, "peaks", axis=1)
