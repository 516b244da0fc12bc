"""The contact image: each taxel's mean over the window, as a fraction of full scale.

Why: the per-pad summaries (``hand``, ``stats``) keep how hard and where on average a pad is
pressed, but not the *shape* of the contact, which says what is held and how (a thin pen, a ball,
a handle touch different taxels). On real SDH-2 recordings a plain RBF SVM on the flattened window
beat the summaries on object tasks for that reason; the mean image carries the same shape at a
fifteenth of the size and costs two ONNX nodes (ReduceMean over time, Mul). Order: the channels'
own (wire order), one feature per taxel.
"""

from __future__ import annotations

import numpy as np

from trainer.features.base import FeatureFamily
from trainer.numerics import U32, gamma

__all__ = ["ContactImage"]


class ContactImage(FeatureFamily):
    """Per-taxel mean over the window / ``fullscale``; ``pad_sizes`` only check the channel count."""

    def __init__(self, pad_sizes=None, pad_shapes=None, fullscale: float = 4095.0):
        self.pad_sizes = pad_sizes
        self.pad_shapes = pad_shapes
        self.fullscale = fullscale

    def _fit(self, X, y) -> None:
        self.n_features_out_ = int(self.n_channels_)

    def _transform(self, X: np.ndarray) -> np.ndarray:
        return np.asarray(X, dtype=np.float64).mean(axis=2) / float(self.fullscale)

    def error_bounds(self, X) -> np.ndarray:
        """A float32 mean of T values, then one product: ``gamma(T + 2)`` times the mean of |x|."""
        X = np.abs(np.asarray(self._check(X), dtype=np.float64))
        return (gamma(X.shape[2] + 2) + U32) * X.mean(axis=2) / float(self.fullscale)

    def onnx_nodes(self, g, frames: str) -> str:
        mean = g.op("ReduceMean", [frames], "taxel_mean", axes=[1], keepdims=0)  # [N, C]
        return g.op("Mul", [mean, g.const("inv_fullscale", 1.0 / float(self.fullscale))], "contact_image")

    def get_feature_names_out(self, input_features=None) -> np.ndarray:
        return np.asarray([f"taxel{c}_mean" for c in range(int(self.n_channels_))], dtype=object)
