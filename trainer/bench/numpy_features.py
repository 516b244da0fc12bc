"""The feature default's decision in plain numpy, read from its ONNX graph: a yardstick for latency.

The hand-designed features (``trainer.features.hand``) and the per-pad level statistics
(``trainer.features.pad_stats``), in the order the metadata lists them, then the scaler and the
RBF (or linear) SVM (``numpy_graph.SvmHead``). The arithmetic follows the graph's nodes step by
step in float32 (all pads at once as one ``[G, S, T]`` tensor, the zero-median shortcut, the DFT as
a MatMul), so the scores agree with the graph's within float32 rounding. Every constant is the
graph's own initializer. ``NumpyFeatures.of(parts)`` returns None for any other graph.
"""

from __future__ import annotations

import numpy as np

from trainer.bench.numpy_graph import GraphParts, SvmHead

FAMILIES = ("hand", "stats")
_HAND = ("pad_moments", "centre", "time_rows", "band_rows", "tiny", "step_mean", "dx2_dy2", "touch_weights")
_STATS = ("stats_moments", "inv_size", "contact_level", "area_weights")
_BEFORE = ("inv_count", "inv_sqrt_t", "inv_fs", "inv_size_fs", "stats_time_rows", "padding_slots")
"""Initializers only graphs exported before the current layout have (read as another kind: None)."""


class NumpyFeatures:
    """``__call__(window [T, C] float32) -> (label, scores [n_classes])`` in float32 numpy."""

    def __init__(self, parts: GraphParts, families: tuple[str, ...]) -> None:
        self.families = families
        p = parts.first
        if parts.has("pad_slots"):
            self.slots = p("pad_slots")  # [G, S]
        else:  # pads of one size in channel order: a reshape
            _, n_pads, size, _ = p("pad_shape")
            self.slots = np.arange(n_pads * size).reshape(n_pads, size)
        self.n_pads, self.n_channels = self.slots.shape[0], int(self.slots.max()) + 1
        if "hand" in families:
            (self.kinds, self.centre, self.time_rows, self.band_rows, self.tiny, self.step_mean, self.pair,
             self.touch_weights) = (p(k) for k in _HAND)  # kinds [G, 3, S]: 1, x, y of each slot over the size
            self.std_weights = p("std_weights") if parts.has("std_weights") else None
            self.offset = p("median_offset")[:, :, 0] if parts.has("median_offset") else None
        else:
            self.rise = p("rise")
        if "stats" in families:
            self.stats_kinds, self.inv_size, self.contact_level, self.area_weights = (p(k) for k in _STATS)
        self.head = SvmHead(parts)

    @classmethod
    def of(cls, parts: GraphParts) -> NumpyFeatures | None:
        """From a graph of hand and/or stats features, or None (another kind: not implemented here)."""
        families = tuple(parts.meta.get("features", {}).get("families", ()))
        if parts.meta.get("model_kind") != "feature_svm" or not families or set(families) - set(FAMILIES):
            return None
        needed = (_HAND if "hand" in families else ("rise",)) + (_STATS if "stats" in families else ())
        if not parts.has(*needed) or not SvmHead.readable(parts) or any(parts.has(k) for k in _BEFORE):
            return None
        if not (parts.has("pad_slots") or parts.has("pad_shape")):
            return None
        if "hand" in families and parts.has("std_weights") and not parts.has("median_offset"):
            return None  # pads whose padding does not split evenly: the graph takes medians pad by pad
        return cls(parts, families)

    def __call__(self, window: np.ndarray) -> tuple[int, np.ndarray]:
        x = window.reshape(-1, self.n_channels)
        padded = x.T[self.slots]  # [G, S, T]: padding slots repeat a taxel of their pad
        peak = padded.max(axis=(1, 2))
        rows, signal_mean = self._rows(padded)
        blocks = [rows.ravel()]  # the series' rows, joined once (``FeatureSVC.onnx_features``)
        for family in self.families:  # the peak twice with both families (the same columns are taken)
            blocks += [peak, self._median(padded), self._std(padded, signal_mean)] if family == "hand" else [peak]
        return self.head(np.concatenate(blocks))

    def _series(self, padded: np.ndarray) -> np.ndarray:
        """``pad_series._hand_series`` and ``_stats_series``: ``[G, K, T]``."""
        parts = []
        if "hand" in self.families:
            moments = self.kinds @ padded  # [G, 3, T]
            signal, mxy = moments[:, :1], moments[:, 1:]
            pressed = signal > 0
            safe = np.where(pressed, signal, np.float32(1.0))
            parts += [signal, np.where(pressed, mxy / safe, self.centre)]
        if "stats" in self.families:
            moments = self.stats_kinds @ np.abs(padded)  # [G, 3, T]
            contact = (padded >= self.contact_level).astype(np.float32)
            parts += [moments[:, :1], self.area_weights @ contact, moments[:, 1:] / (moments[:, :1] + self.inv_size)]
        return np.concatenate(parts, axis=1)

    def _rows(self, padded: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``pad_series._time_nodes``: rows ``[G, K, width]`` of every series, and the pads' mean value."""
        series = self._series(padded)
        mean = series.mean(axis=2, keepdims=True)
        centred = series - mean
        root_sq = np.sqrt(np.einsum("gkt,gkt->gk", centred, centred))[..., None] if "stats" in self.families else mean
        if "hand" not in self.families:
            return np.concatenate([mean, root_sq, centred @ self.rise], axis=2), mean[:, 0, 0]
        over = centred @ self.time_rows  # [G, K, 2B + T-1 + 2]: DFT, steps, deriv, rise
        sq = over * over
        energy4 = sq @ self.band_rows  # [G, K, 4]
        shares = energy4[..., :3] / np.maximum(energy4[..., 3:], self.tiny)
        log_energy = np.log(energy4[..., 3:] + np.float32(1.0))
        speed = np.sqrt(self.pair @ sq) @ self.step_mean
        return np.concatenate([mean, root_sq, shares, log_energy, over, speed], axis=2), mean[:, 0, 0]

    def _median(self, padded: np.ndarray) -> np.ndarray:
        """``pad_batch.median_nodes``: 0 when fewer than half of every pad's values can be non-zero, else
        the middle of the padded values (padding offset by +-inf in equal numbers)."""
        touched = (np.abs(padded).sum(axis=2) > 0).astype(np.float32)  # [G, S]
        if np.einsum("gs,gs->g", self.touch_weights[:, 0], touched).max() <= 1:
            return np.zeros(self.n_pads, dtype=np.float32)
        values = padded if self.offset is None else padded + self.offset[:, :, None]
        values = values.reshape(self.n_pads, -1)
        total = values.shape[1]
        k = total // 2
        if total % 2:
            return np.partition(values, k, axis=1)[:, k]
        part = np.partition(values, (k - 1, k), axis=1)
        return (part[:, k - 1] + part[:, k]) * np.float32(0.5)

    def _std(self, padded: np.ndarray, mean: np.ndarray) -> np.ndarray:
        """``hand._std_nodes``: two passes; padded pads weigh each slot's squares (0 on padding), pads of
        one size give the root of the sum of squares (the graph's factor is in the SVM's weights)."""
        dev = padded - mean[:, None, None]
        if self.std_weights is not None:
            return np.sqrt((np.einsum("gst,gst->gs", dev, dev) * self.std_weights).sum(axis=1))
        return np.sqrt(np.einsum("gst,gst->g", dev, dev))
