"""Bag-of-Words of tactile time series (the paper's feature generator) as a scikit-learn transformer.

The float64 arithmetic here is the reference the exported ONNX graph must reproduce
(docs/INTERFACES.md, "Trainer estimators"):

1. a series (one taxel of one case) is *active* when it is not all zero in the raw window;
2. ``D = X[:, :, 1:] - X[:, :, :-1]`` (time derivative, length T-1);
3. windows ``D[n, c, s:s+W]`` for s = 0 .. T-1-W;
4. each window's word is ``argmin_k ||window - codebook_[k]||^2`` (ties go to the lowest k);
5. a case's histogram counts the words of its active series' windows, divided by the number of
   those windows (all zeros when none), one histogram per case or one per pad group.

Input is ``(n_cases, n_channels, n_timepoints)`` (aeon/sktime convention). A 2-D ``X`` is read as
``(n_cases, n_timepoints)`` with a single channel, which is how scikit-learn's estimator checks
feed it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.cluster import KMeans
from sklearn.utils import check_array, check_random_state
from sklearn.utils.validation import check_is_fitted

KMEANS_N_INIT = 3
"""k-means restarts: fixed so that a seed gives the same codebook everywhere."""

_CHUNK_ELEMENTS = 4_000_000
"""Windows x words handled at once by the nearest-word search (bounds memory to ~100 MB)."""


def as_cases(X, *, reset_dtype: bool = True) -> np.ndarray:
    """Validate X and return it as float64 ``(n_cases, n_channels, n_timepoints)``.

    2-D input is ``(n_cases, n_timepoints)`` with one channel. NaN, infinity, complex, sparse
    and object input raise ValueError/TypeError as scikit-learn estimators do.
    """
    arr = check_array(X, dtype=np.float64, allow_nd=True, ensure_2d=True, ensure_all_finite=True)
    if arr.ndim == 2:
        arr = arr[:, None, :]
    if arr.ndim != 3:
        raise ValueError(f"X must be 2-D (n_cases, n_timepoints) or 3-D (n_cases, n_channels, n_timepoints), got {arr.ndim}-D")
    return arr


def active_series(X: np.ndarray) -> np.ndarray:
    """Boolean ``(n_cases, n_channels)``: True where the raw series is not all zero."""
    return np.any(X != 0, axis=2)


def derivative_windows(X: np.ndarray, window: int) -> np.ndarray:
    """All windows of the time derivative: float64 ``(n_cases, n_channels, n_windows, window)``.

    ``n_windows = n_timepoints - window`` (the derivative has n_timepoints - 1 values).
    """
    X = np.asarray(X, dtype=np.float64)
    n_t = X.shape[2]
    if n_t - 1 < window:
        raise ValueError(
            f"window W={window} needs at least W+1={window + 1} timepoints per series, got {n_t}"
        )
    deriv = X[:, :, 1:] - X[:, :, :-1]
    return np.lib.stride_tricks.sliding_window_view(deriv, window, axis=2)


def nearest_words(windows: np.ndarray, codebook: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest codeword of each window and the squared-distance margin to the runner-up.

    ``windows``: ``(..., W)``; returns ``words`` int64 ``(...)`` (ties -> lowest index) and
    ``margins`` float64 ``(...)`` = second-smallest minus smallest squared distance (0 at a tie,
    inf with a single word). Distances are computed as sums of squared differences, not by the
    expanded dot-product form, so the reference does not lose precision.
    """
    codebook = np.asarray(codebook, dtype=np.float64)
    shape = windows.shape[:-1]
    flat = np.asarray(windows, dtype=np.float64).reshape(-1, windows.shape[-1])
    n_words = codebook.shape[0]
    words = np.empty(len(flat), dtype=np.int64)
    margins = np.empty(len(flat), dtype=np.float64)
    step = max(1, _CHUNK_ELEMENTS // max(1, n_words * flat.shape[1]))
    for start in range(0, len(flat), step):
        block = flat[start : start + step]
        dist = np.empty((len(block), n_words), dtype=np.float64)
        for k in range(n_words):
            diff = block - codebook[k]
            dist[:, k] = np.einsum("ij,ij->i", diff, diff)
        best = np.argmin(dist, axis=1)
        words[start : start + step] = best
        if n_words > 1:
            part = np.partition(dist, 1, axis=1)
            margins[start : start + step] = part[:, 1] - part[:, 0]
        else:
            margins[start : start + step] = np.inf
    return words.reshape(shape), margins.reshape(shape)


def channel_groups(pad_sizes: Sequence[int]) -> np.ndarray:
    """Group index of each channel, from consecutive pad sizes (e.g. (68, 68) -> 0..0, 1..1)."""
    return np.repeat(np.arange(len(pad_sizes)), np.asarray(pad_sizes, dtype=np.int64))


def word_histograms(words: np.ndarray, active: np.ndarray, pad_sizes: Sequence[int], n_words: int) -> np.ndarray:
    """Normalised histograms ``(n_cases, n_groups * n_words)`` from words ``(n, c, S)`` and ``active`` ``(n, c)``."""
    n_cases, _, n_windows = words.shape
    groups = channel_groups(pad_sizes)
    n_groups = len(pad_sizes)
    weights = np.broadcast_to(active[:, :, None], words.shape).astype(np.float64)
    case_idx = np.arange(n_cases)[:, None, None]
    flat_idx = (case_idx * n_groups + groups[None, :, None]) * n_words + words
    counts = np.bincount(flat_idx.ravel(), weights=weights.ravel(), minlength=n_cases * n_groups * n_words)
    counts = counts.reshape(n_cases, n_groups, n_words)
    n_active = np.zeros((n_cases, n_groups))
    np.add.at(n_active, (slice(None), groups), active.astype(np.float64))
    totals = n_active * n_windows
    with np.errstate(invalid="ignore", divide="ignore"):
        hist = np.where(totals[:, :, None] > 0, counts / np.maximum(totals, 1)[:, :, None], 0.0)
    return hist.reshape(n_cases, n_groups * n_words)


class BagOfWords(TransformerMixin, BaseEstimator):
    """Histogram of nearest k-means words over derivative windows of the active taxel series.

    Parameters: ``n_words`` (K), ``window`` (W), ``per_pad`` (one histogram per pad group, needs
    ``pad_sizes``: channels per pad, consecutive, summing to n_channels), ``max_windows`` (the
    k-means sample is a seeded random subset of at most this many windows), ``random_state``.

    Fitted: ``codebook_`` float64 ``[K, W]``, ``pad_sizes_`` tuple, ``n_features_out_``,
    ``n_channels_``, ``n_timepoints_``, ``n_features_in_`` (= n_channels * n_timepoints).
    """

    def __init__(
        self,
        n_words: int = 10,
        window: int = 7,
        per_pad: bool = False,
        pad_sizes: Sequence[int] | None = None,
        max_windows: int = 200000,
        random_state=None,
    ):
        self.n_words = n_words
        self.window = window
        self.per_pad = per_pad
        self.pad_sizes = pad_sizes
        self.max_windows = max_windows
        self.random_state = random_state

    # -- fitting ------------------------------------------------------------------------------
    def _resolve_pad_sizes(self, n_channels: int) -> tuple[int, ...]:
        if self.pad_sizes is not None:
            sizes = tuple(int(s) for s in self.pad_sizes)
            if any(s <= 0 for s in sizes) or sum(sizes) != n_channels:
                raise ValueError(f"pad_sizes {sizes} must be positive and sum to n_channels={n_channels}")
        elif self.per_pad:
            raise ValueError("per_pad=True needs pad_sizes (channels of each pad, in channel order)")
        else:
            sizes = (n_channels,)
        return sizes if self.per_pad else (n_channels,)

    def _check_params(self) -> None:
        if int(self.n_words) < 1:
            raise ValueError(f"n_words must be >= 1, got {self.n_words}")
        if int(self.window) < 1:
            raise ValueError(f"window must be >= 1, got {self.window}")
        if int(self.max_windows) < 1:
            raise ValueError(f"max_windows must be >= 1, got {self.max_windows}")

    def fit(self, X, y=None):
        """Learn the codebook by k-means on the derivative windows of the active series."""
        self._check_params()
        X = as_cases(X)
        _, n_channels, n_timepoints = X.shape
        if n_timepoints < 2:
            raise ValueError(
                f"X has {n_timepoints} feature(s) (timepoints) per series; the derivative needs at least 2"
            )
        pad_sizes = self._resolve_pad_sizes(n_channels)
        windows = derivative_windows(X, int(self.window))
        active = active_series(X)
        sample = windows[active].reshape(-1, int(self.window))
        rng = check_random_state(self.random_state)
        if len(sample) > int(self.max_windows):
            pick = np.sort(rng.choice(len(sample), size=int(self.max_windows), replace=False))
            sample = sample[pick]
        if len(sample) < int(self.n_words):
            raise ValueError(
                f"only {len(sample)} windows of active (not all-zero) series to learn {self.n_words} words from"
            )
        kmeans = KMeans(n_clusters=int(self.n_words), n_init=KMEANS_N_INIT, random_state=rng)
        kmeans.fit(sample)
        self.codebook_ = np.ascontiguousarray(kmeans.cluster_centers_, dtype=np.float64)
        self.inertia_ = float(kmeans.inertia_)
        self.pad_sizes_ = pad_sizes
        self.n_features_out_ = int(self.n_words) * len(pad_sizes)
        self.n_channels_ = n_channels
        self.n_timepoints_ = n_timepoints
        self.n_features_in_ = n_channels * n_timepoints
        return self

    # -- transforming -------------------------------------------------------------------------
    def _check_X(self, X) -> np.ndarray:
        check_is_fitted(self, "codebook_")
        X = as_cases(X)
        if X.shape[1:] != (self.n_channels_, self.n_timepoints_):
            raise ValueError(
                f"X has {X.shape[1] * X.shape[2]} features, but {type(self).__name__} is expecting "
                f"{self.n_features_in_} features as input ({self.n_channels_} channels x {self.n_timepoints_} "
                f"timepoints, got {X.shape[1]} x {X.shape[2]})"
            )
        return X

    def words(self, X) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per-window words, margins (runner-up minus best squared distance) and active mask.

        Returns ``words`` int64 ``(n, c, S)``, ``margins`` float64 ``(n, c, S)``, ``active`` bool
        ``(n, c)``. ``handover verify`` uses the margins to tell true near-ties from errors.
        """
        X = self._check_X(X)
        windows = derivative_windows(X, int(self.window))
        words, margins = nearest_words(windows, self.codebook_)
        return words, margins, active_series(X)

    def transform(self, X) -> np.ndarray:
        """Normalised word histograms, float64 ``(n_cases, n_features_out_)``."""
        words, _, active = self.words(X)
        return word_histograms(words, active, self.pad_sizes_, int(self.n_words))

    def get_feature_names_out(self, input_features=None) -> np.ndarray:
        check_is_fitted(self, "codebook_")
        names = [f"pad{g}_word{k}" for g in range(len(self.pad_sizes_)) for k in range(int(self.n_words))]
        return np.asarray(names, dtype=object)

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.input_tags.three_d_array = True
        tags.transformer_tags.preserves_dtype = ["float64"]
        return tags
