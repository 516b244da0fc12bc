"""The paper's hand-designed baseline: summary features per pad, standardised, with an SVM.

The paper reports about 60 % for these. Per pad over the window: max, mean, median, std; the FFT
energy share in three bands and log total energy of the mean-pressure signal; its mean derivative;
the centre of pressure; and, as a documented stand-in for optical flow (6 x 13 taxels are too
coarse), the centre of pressure's net displacement and mean speed: 14 features per pad.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from sklearn.base import BaseEstimator, ClassifierMixin, TransformerMixin
from sklearn.utils.validation import check_is_fitted

from trainer.bow import as_cases
from trainer.classifier import SVMHead, check_training_data

__all__ = ["FEATURES_PER_PAD", "BaselineSVC", "HandFeatures", "pad_features"]

FEATURES_PER_PAD = (
    "max", "mean", "median", "std",
    "fft_low", "fft_mid", "fft_high", "fft_log_energy",
    "mean_derivative", "cop_x", "cop_y", "cop_dx", "cop_dy", "cop_speed",
)


def _resolve_shapes(pad_shapes, n_channels: int) -> list[tuple[int, int]]:
    if pad_shapes is None:
        return [(1, n_channels)]
    shapes = [(int(r), int(c)) for r, c in pad_shapes]
    if sum(r * c for r, c in shapes) != n_channels:
        raise ValueError(f"pad_shapes {shapes} cover {sum(r * c for r, c in shapes)} taxels, X has {n_channels} channels")
    return shapes


def pad_features(P: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """The 14 features of one pad block ``(n, rows*cols, T)`` -> ``(n, 14)``."""
    n, _, T = P.shape
    flat = P.reshape(n, -1)
    signal = P.mean(axis=1)  # (n, T)
    spectrum = np.abs(np.fft.rfft(signal - signal.mean(axis=1, keepdims=True), axis=1)) ** 2
    bins = spectrum[:, 1:]
    total = bins.sum(axis=1)
    bands = np.array_split(np.arange(bins.shape[1]), 3) if bins.shape[1] >= 3 else [np.arange(bins.shape[1])] * 3
    shares = np.stack([bins[:, b].sum(axis=1) for b in bands], axis=1) / np.maximum(total, 1e-12)[:, None]
    deriv = np.diff(signal, axis=1).mean(axis=1) if T > 1 else np.zeros(n)

    ys, xs = np.divmod(np.arange(rows * cols), cols)
    weight = P.sum(axis=1)  # (n, T)
    safe = np.where(weight > 0, weight, 1.0)
    cop_x = np.where(weight > 0, np.einsum("nct,c->nt", P, xs) / safe, (cols - 1) / 2)
    cop_y = np.where(weight > 0, np.einsum("nct,c->nt", P, ys) / safe, (rows - 1) / 2)
    speed = np.hypot(np.diff(cop_x, axis=1), np.diff(cop_y, axis=1)).mean(axis=1) if T > 1 else np.zeros(n)
    return np.column_stack([
        flat.max(axis=1), flat.mean(axis=1), np.median(flat, axis=1), flat.std(axis=1),
        shares, np.log1p(total),
        deriv,
        cop_x.mean(axis=1), cop_y.mean(axis=1),
        cop_x[:, -1] - cop_x[:, 0], cop_y[:, -1] - cop_y[:, 0], speed,
    ])


class HandFeatures(TransformerMixin, BaseEstimator):
    """Hand-designed features per pad; ``pad_shapes`` = [(rows, cols), ...] in channel order."""

    def __init__(self, pad_shapes: Sequence[tuple[int, int]] | None = None):
        self.pad_shapes = pad_shapes

    def fit(self, X, y=None):
        X = as_cases(X)
        self.shapes_ = _resolve_shapes(self.pad_shapes, X.shape[1])
        self.n_channels_, self.n_timepoints_ = X.shape[1], X.shape[2]
        self.n_features_in_ = X.shape[1] * X.shape[2]
        return self

    def transform(self, X) -> np.ndarray:
        check_is_fitted(self, "shapes_")
        X = as_cases(X)
        if X.shape[1:] != (self.n_channels_, self.n_timepoints_):
            raise ValueError(
                f"X has {X.shape[1] * X.shape[2]} features, but {type(self).__name__} is expecting "
                f"{self.n_features_in_} features as input"
            )
        out, start = [], 0
        for rows, cols in self.shapes_:
            out.append(pad_features(X[:, start : start + rows * cols], rows, cols))
            start += rows * cols
        return np.concatenate(out, axis=1)

    def get_feature_names_out(self, input_features=None) -> np.ndarray:
        check_is_fitted(self, "shapes_")
        return np.asarray([f"pad{p}_{f}" for p in range(len(self.shapes_)) for f in FEATURES_PER_PAD], dtype=object)

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.input_tags.three_d_array = True
        return tags


class BaselineSVC(SVMHead, ClassifierMixin, BaseEstimator):
    """HandFeatures + StandardScaler + SVC (one-vs-one), C/gamma by the same search as BowSVC; the
    checks, scaling, prediction and decision scores are ``SVMHead``'s, shared with BowSVC and FlatSVC."""

    def __init__(self, pad_shapes=None, kernel: str = "rbf", C: float | None = None, gamma=None):
        self.pad_shapes = pad_shapes
        self.kernel = kernel
        self.C = C
        self.gamma = gamma

    def fit(self, X, y):
        X, y, self.classes_ = check_training_data(self, X, y)
        self.features_ = HandFeatures(self.pad_shapes).fit(X)
        self._fit_scaled_svm(self.features_.transform(X), y)
        self.n_features_in_ = self.features_.n_features_in_
        return self

    def transform_histograms(self, X) -> np.ndarray:
        """The hand-designed features before scaling."""
        check_is_fitted(self, "svm_")
        return self.features_.transform(X)

    def svm_input(self, features: np.ndarray) -> np.ndarray:
        return self.scaler_.transform(features)
