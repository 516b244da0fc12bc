"""The flattened-series SVM: a reference classifier that sees every raw value of the window.

The whole ``C x T`` window flattened channel-major, standardised, and fed to an SVC searched like the
BoW classifier: static pressure, position and timing all reach the SVM. It exports to one ONNX graph
too, so its latency is measured the same way.
"""

from __future__ import annotations

import numpy as np
from sklearn.base import BaseEstimator, ClassifierMixin
from sklearn.utils.validation import check_is_fitted

from trainer.bow import check_case_shape
from trainer.classifier import SVMHead, check_training_data

__all__ = ["FlatSVC"]


class FlatSVC(SVMHead, ClassifierMixin, BaseEstimator):
    """StandardScaler + SVC on the flattened ``(n_channels, n_timepoints)`` window.

    Fitted: ``scaler_``, ``svm_``, ``classes_``, ``best_params_``, ``n_channels_``,
    ``n_timepoints_``, ``n_features_in_``.
    """

    def __init__(self, kernel: str = "rbf", C: float | None = None, gamma: float | str | None = None):
        self.kernel = kernel
        self.C = C
        self.gamma = gamma

    def fit(self, X, y):
        X, y, self.classes_ = check_training_data(self, X, y)
        _, self.n_channels_, self.n_timepoints_ = X.shape
        self.n_features_in_ = self.n_channels_ * self.n_timepoints_
        self._fit_scaled_svm(X.reshape(len(X), -1), y)
        return self

    def transform_histograms(self, X) -> np.ndarray:
        """The flattened raw window (the graph's ``histogram`` tensor; no codebook here)."""
        check_is_fitted(self, "svm_")
        X = check_case_shape(self, X)
        return X.reshape(len(X), -1)

    def svm_input(self, hist: np.ndarray) -> np.ndarray:
        return self.scaler_.transform(hist)

