"""Static/level features per pad: what pressure, contact area and centre of pressure are over the
window and how they change across it (the information the derivative histogram removes).

From the per-pad signals of ``trainer.features.signals`` (pressure, area, cx, cy per pad, ``S = 4G``)
over the window: their mean, their standard deviation over time and their change (last frame minus
first), then each pad's peak taxel / fullscale. Order: ``[mean (S), std (S), change (S), peak (G)]``.
"""

from __future__ import annotations

import numpy as np

from trainer.features.base import FeatureFamily, OnnxParts, pad_bounds
from trainer.features.pad_batch import PadBatch, peak_nodes
from trainer.features.pad_series import STATS_SERIES, SeriesNeed, pad_series_nodes
from trainer.features.signals import SIGNALS, pad_signals, signal_error_bounds
from trainer.numerics import U32, gamma

__all__ = ["PadStats"]


class PadStats(FeatureFamily):
    """Per-pad level statistics; ``pad_sizes`` (and optionally ``pad_shapes``) in channel order."""

    def __init__(self, pad_sizes=None, pad_shapes=None, fullscale: float = 4095.0):
        self.pad_sizes = pad_sizes
        self.pad_shapes = pad_shapes
        self.fullscale = fullscale

    def _fit(self, X, y) -> None:
        n_pads = len(self.shapes_)
        self.n_features_out_ = 3 * len(SIGNALS) * n_pads + n_pads

    def _transform(self, X: np.ndarray) -> np.ndarray:
        s = pad_signals(X, self.shapes_, float(self.fullscale))
        mean = s.mean(axis=2)
        std = np.sqrt(((s - mean[:, :, None]) ** 2).mean(axis=2))
        peak = np.stack([X[:, a:b].max(axis=(1, 2)) for a, b in pad_bounds(self.shapes_)], axis=1)
        return np.concatenate([mean, std, s[:, :, -1] - s[:, :, 0], peak / float(self.fullscale)], axis=1)

    def error_bounds(self, X) -> np.ndarray:
        """Bound on |float32 - float64| per feature: the signals' bound carried through mean, the
        two-pass variance and its square root, and the difference of two centred frames."""
        X = self._check(X)
        s = pad_signals(X, self.shapes_, float(self.fullscale))
        e = signal_error_bounds(X, self.shapes_, float(self.fullscale))
        n_t = s.shape[2]
        mean = s.mean(axis=2)
        e_mean = e.mean(axis=2) + gamma(n_t + 1) * np.abs(s).mean(axis=2)
        c = s - mean[:, :, None]
        e_c = e + e_mean[:, :, None] + U32 * (np.abs(s) + np.abs(mean)[:, :, None])
        var = (c**2).mean(axis=2)
        e_var = (2 * np.abs(c) * e_c + e_c**2).mean(axis=2) + gamma(n_t + 2) * var
        std = np.sqrt(var)
        e_std = np.minimum(np.sqrt(e_var), e_var / np.maximum(std, 1e-300)) + U32 * std
        # the graph takes last - first of the centred signal: both differences round (the mean cancels)
        e_change = e[:, :, -1] + e[:, :, 0] + 2 * U32 * (np.abs(s[:, :, -1]) + np.abs(s[:, :, 0]) + np.abs(mean))
        peak = np.stack([np.abs(X[:, a:b]).max(axis=(1, 2)) for a, b in pad_bounds(self.shapes_)], axis=1)
        return np.concatenate([e_mean, e_std, e_change, U32 * peak / float(self.fullscale)], axis=1)

    def onnx_parts(self, g, frames: str) -> OnnxParts:
        """From the pads' series (``trainer.features.pad_series``, shared with the hand family's): the
        mean, the change (last - first of the centred series) and the root of the centred squares
        (the std times sqrt(T): two passes, a constant signal's is exactly 0), and the peak taxel
        (unscaled: its 1 / fullscale is in the SVM's weights). Parts: the series' rows, peak."""
        n_t, n_pads = int(self.n_timepoints_), len(self.shapes_)
        series = pad_series_nodes(g, frames, self.shapes_, n_t, SeriesNeed(hand=False, fullscale=float(self.fullscale)))
        rows, n_rows = series.columns, n_pads * len(series.columns.series) * series.columns.width
        columns = [rows.column(p, s, quantity) for quantity in ("mean", "root_sq", "change")
                   for s in STATS_SERIES for p in range(n_pads)] + [n_rows + p for p in range(n_pads)]
        n_sig = len(SIGNALS) * n_pads
        scales = np.concatenate([np.ones(n_sig), np.full(n_sig, np.sqrt(n_t)), np.ones(n_sig),
                                 np.full(n_pads, float(self.fullscale))])
        return OnnxParts([series.flat, self._peak_nodes(g, frames)], np.asarray(columns), n_rows + n_pads, scales,
                         (n_rows, n_pads))

    def _peak_nodes(self, g, frames: str) -> str:
        """Each pad's peak taxel ``[N, G]`` (unscaled; shares the hand family's nodes when both are in)."""
        return peak_nodes(g, PadBatch.of(self.shapes_).nodes(g, frames))

    def get_feature_names_out(self, input_features=None) -> np.ndarray:
        pads = range(len(self.shapes_))
        sig = [f"pad{p}_{s}" for s in SIGNALS for p in pads]
        return np.asarray([f"{n}_{stat}" for stat in ("mean", "std", "change") for n in sig]
                          + [f"pad{p}_peak" for p in pads], dtype=object)
