"""Per-pad signals over time: the static information the derivative histogram throws away.

For every pad (a ``rows x cols`` grid, row-major, x fastest) and every frame:

- ``pressure``: mean taxel magnitude / fullscale;
- ``area``: share of the pad's taxels at or above ``contact_fraction`` of full scale (contact area);
- ``cx``, ``cy``: centre of pressure relative to the pad centre, in pad widths/heights
  (``sum |x| * pos / (sum |x| + fullscale)``: one full-scale taxel of damping at the centre keeps it
  smooth and bounded where nothing presses, instead of a 0/0 switch that float32 could flip).

Taxels are non-negative on the wire; magnitudes (``|x|``) make negative stress input harmless.
Signals come signal-major: ``[pressure_pad0 .. pressure_padG, area_pad0 .., cx_pad0 .., cy_pad0 ..]``.
The float64 functions here are the reference the ONNX nodes (``signal_nodes``) must reproduce; the
nodes are two MatMuls over the taxels, so the graph stays Conv/MatMul-shaped.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["CONTACT_FRACTION", "SIGNALS", "pad_shapes_for", "pad_signals", "signal_error_bounds", "signal_nodes"]

SIGNALS = ("pressure", "area", "cx", "cy")
CONTACT_FRACTION = 0.05
"""A taxel is in contact at 5 % of full scale (the window rule of the real tasks in the compare)."""
PAD_WIDTH = 6
"""Taxels across an SDH-2 pad (6 x 13 distal, 6 x 14 proximal), for pads given by size only."""


def pad_shapes_for(pad_sizes: Sequence[int], pad_shapes: Sequence[tuple[int, int]] | None = None
                   ) -> list[tuple[int, int]]:
    """``(rows, cols)`` per pad: the given shapes, else SDH-2 pads (6 wide) where the size allows, else one row."""
    sizes = [int(s) for s in pad_sizes]
    if pad_shapes is not None:
        shapes = [(int(r), int(c)) for r, c in pad_shapes]
        if [r * c for r, c in shapes] != sizes:
            raise ValueError(f"pad_shapes {shapes} do not match pad_sizes {sizes}")
        return shapes
    return [(s // PAD_WIDTH, PAD_WIDTH) if s % PAD_WIDTH == 0 else (1, s) for s in sizes]


def signal_matrices(pad_shapes: Sequence[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weights over the taxels ``[C, G]``: ones (pad sum), x positions, y positions (pad units, centred)."""
    n_channels = sum(r * c for r, c in pad_shapes)
    ones, xs, ys = (np.zeros((n_channels, len(pad_shapes))) for _ in range(3))
    start = 0
    for g, (rows, cols) in enumerate(pad_shapes):
        y, x = np.divmod(np.arange(rows * cols), cols)
        stop = start + rows * cols
        ones[start:stop, g] = 1.0
        xs[start:stop, g] = (x - (cols - 1) / 2.0) / cols
        ys[start:stop, g] = (y - (rows - 1) / 2.0) / rows
        start = stop
    return ones, xs, ys


def pad_signals(X: np.ndarray, pad_shapes: Sequence[tuple[int, int]], fullscale: float,
                contact_fraction: float = CONTACT_FRACTION) -> np.ndarray:
    """Float64 signals ``(n, 4G, T)`` of cases ``(n, C, T)`` (see the module docstring)."""
    X = np.asarray(X, dtype=np.float64)
    ones, xs, ys = signal_matrices(pad_shapes)
    sizes = ones.sum(axis=0)[None, :, None]
    n_pads = len(pad_shapes)
    # one BLAS product per input (an unoptimised einsum over n, c, t took most of a stream model's training)
    moments = _over_taxels(np.abs(X), np.concatenate([ones, xs, ys], axis=1))
    total, mx, my = moments[:, :n_pads], moments[:, n_pads : 2 * n_pads], moments[:, 2 * n_pads :]
    den = total + fullscale
    contact = _over_taxels((contact_fraction * fullscale <= X).astype(np.float64), ones)
    return np.concatenate([total / (sizes * fullscale), contact / sizes, mx / den, my / den], axis=1)


def _over_taxels(X: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``(n, C, T)`` cases weighted over the taxels by ``weights`` ``[C, K]``: ``(n, K, T)``."""
    return np.matmul(np.ascontiguousarray(weights.T), X)


def signal_error_bounds(X: np.ndarray, pad_shapes: Sequence[tuple[int, int]], fullscale: float) -> np.ndarray:
    """Bound ``(n, 4G, T)`` on |float32 graph - float64| of the signals (sums of at most C_pad
    terms, one division): gamma(C_pad + 4) times the signal's magnitude, and exact area counts."""
    from trainer.numerics import gamma

    largest = max(r * c for r, c in pad_shapes)
    ones, xs, ys = signal_matrices(pad_shapes)
    mag = np.abs(np.asarray(X, dtype=np.float64))
    total = np.einsum("nct,cg->ngt", mag, ones)
    n_pads = len(pad_shapes)
    scale = np.concatenate([
        pad_signals(mag, pad_shapes, fullscale)[:, : 2 * n_pads],
        # the centroid's numerator sums |x| |pos| terms whose float32 rounding does not cancel
        np.einsum("nct,cg->ngt", mag, np.abs(xs)) / (total + fullscale),
        np.einsum("nct,cg->ngt", mag, np.abs(ys)) / (total + fullscale),
    ], axis=1)
    err = gamma(largest + 4) * scale
    err[:, 2 * n_pads :] *= 2.0  # numerator and denominator each carry a rounding error
    return err


def signal_nodes(g, frames: str, pad_shapes: Sequence[tuple[int, int]], fullscale: float,
                 contact_fraction: float = CONTACT_FRACTION) -> str:
    """ONNX nodes: ``frames`` ``[N, T, C]`` -> signals ``[N, T, 4G]`` (same order as ``pad_signals``)."""
    ones, xs, ys = signal_matrices(pad_shapes)
    sizes = ones.sum(axis=0)
    n_pads = len(pad_shapes)
    mag = g.op("Abs", [frames], "magnitude")
    # the pad sums twice more, so one Add and one Div give both centroids (no broadcast of [N, T, G]
    # over [N, T, 2G] without a node to spare)
    # the pressure's scale in its weights (no Mul after the sum)
    weights = np.concatenate([ones / (sizes * fullscale), xs, ys, ones, ones], axis=1)
    moments = g.op("MatMul", [mag, g.const("pad_moments", weights)], "moments")
    pressure, mxy, total2 = g.name("pressure"), g.name("mxy"), g.name("total2")
    g.op("Split", [moments, g.const("split3", [n_pads, 2 * n_pads, 2 * n_pads], np.int64)],
         outputs=[pressure, mxy, total2], axis=2)
    den = g.op("Add", [total2, g.const("fullscale", fullscale)], "centroid_den")
    contact = g.op("Cast", [g.op("GreaterOrEqual", [frames, g.const("contact_level", contact_fraction * fullscale)])],
                   "contact", to=1)
    area = g.op("MatMul", [contact, g.const("area_weights", ones / sizes)], "area")
    centroid = g.op("Div", [mxy, den], "centroid")
    return g.op("Concat", [pressure, area, centroid], "signals", axis=2)
