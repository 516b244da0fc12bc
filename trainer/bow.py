"""Bag-of-Words of tactile time series (the paper's feature generator) as a scikit-learn transformer.

The float64 arithmetic here is the reference the exported ONNX graph must reproduce
(docs/INTERFACES.md, "Trainer estimators"):

1. a series (one taxel of one case) is *active* when it is not all zero in the raw window;
2. ``D = X[:, :, 1:] - X[:, :, :-1]`` (time derivative, length T-1);
3. windows ``D[n, c, s:s+W]`` for s = 0 .. T-1-W;
4. each window's word is ``argmin_k ||window - codebook_[k]||^2`` (ties go to the lowest k);
5. a case's histogram counts the words of its active series' windows, divided by the number of
   those windows (all zeros when none), one histogram per case or one per pad group.

Options beyond the paper, each off by default: several window lengths (one codebook each, histograms
concatenated); ``assignment="soft"`` (``softmax_k(-(d_k - min_j d_j) / tau)`` with ``tau`` the unit-free
``temperature`` times the k-means sample's mean squared distance; subtracting the minimum keeps float32
finite); ``level_features`` (per pad the mean level and mean slope over the window, over ``fullscale``,
appended last). Input is ``(n_cases, n_channels, n_timepoints)``; a 2-D ``X`` is one channel.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.cluster import KMeans
from sklearn.utils import check_array, check_random_state
from sklearn.utils.validation import check_is_fitted

from trainer.defaults import PAPER_MODEL

__all__ = [
    "BagOfWords", "active_series", "active_words", "as_cases", "channel_groups", "check_case_shape", "derivative_windows",
    "level_features", "nearest_words"
]

KMEANS_N_INIT = 3
"""k-means restarts: fixed so that a seed gives the same codebook everywhere."""

_CHUNK_ELEMENTS = 4_000_000
"""Windows x words handled at once by the nearest-word search (bounds memory to ~100 MB)."""


def as_cases(X) -> np.ndarray:
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


def check_case_shape(estimator, X) -> np.ndarray:
    """X as float64 cases of the fitted ``(n_channels_, n_timepoints_)``, or scikit-learn's
    "X has N features, but ... is expecting M features" ValueError."""
    X = as_cases(X)
    if X.shape[1:] != (estimator.n_channels_, estimator.n_timepoints_):
        raise ValueError(
            f"X has {X.shape[1] * X.shape[2]} features, but {type(estimator).__name__} is expecting "
            f"{estimator.n_features_in_} features as input ({estimator.n_channels_} channels x "
            f"{estimator.n_timepoints_} timepoints, got {X.shape[1]} x {X.shape[2]})"
        )
    return X


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


def nearest_words(windows: np.ndarray, codebook: np.ndarray, margins: bool = True
                  ) -> tuple[np.ndarray, np.ndarray | None]:
    """Nearest codeword of each window and the squared-distance margin to the runner-up.

    ``windows``: ``(..., W)``; returns ``words`` int64 ``(...)`` (ties -> lowest index) and
    ``margins`` float64 ``(...)`` = second-smallest minus smallest squared distance (0 at a tie,
    inf with a single word; None when not asked for: the histograms need the words alone). Distances
    are computed as sums of squared differences, not by the expanded dot-product form, so the
    reference does not lose precision.
    """
    codebook = np.asarray(codebook, dtype=np.float64)
    shape = windows.shape[:-1]
    flat = np.asarray(windows, dtype=np.float64).reshape(-1, windows.shape[-1])
    n_words = codebook.shape[0]
    words = np.empty(len(flat), dtype=np.int64)
    runner_up = np.empty(len(flat), dtype=np.float64) if margins else None
    step = max(1, _CHUNK_ELEMENTS // max(1, n_words * flat.shape[1]))
    for start in range(0, len(flat), step):
        block = flat[start : start + step]
        dist = np.empty((len(block), n_words), dtype=np.float64)
        for k in range(n_words):
            diff = block - codebook[k]
            dist[:, k] = np.einsum("ij,ij->i", diff, diff)
        best = np.argmin(dist, axis=1)
        words[start : start + step] = best
        if runner_up is None:
            continue
        if n_words > 1:
            part = np.partition(dist, 1, axis=1)
            runner_up[start : start + step] = part[:, 1] - part[:, 0]
        else:
            runner_up[start : start + step] = np.inf
    return words.reshape(shape), None if runner_up is None else runner_up.reshape(shape)


def active_words(X: np.ndarray, active: np.ndarray, codebook: np.ndarray) -> np.ndarray:
    """``nearest_words`` of the active series' windows, int64 ``(n, c, S)``; an inactive series' words
    are 0 (the histograms give them no weight; most taxels of a window are untouched, so this skips most
    of the distances)."""
    n_windows = X.shape[2] - codebook.shape[1]
    words = np.zeros((*active.shape, max(n_windows, 0)), dtype=np.int64)
    words[active] = nearest_words(derivative_windows(X[active][:, None, :], codebook.shape[1])[:, 0], codebook,
                                  margins=False)[0]
    return words


def soft_assignment_sums(windows: np.ndarray, codebook: np.ndarray, tau: float) -> np.ndarray:
    """Per series, the summed soft assignments of its windows: float64 ``(n, c, K)``.

    ``windows``: ``(n, c, S, W)``. Each window's weights are ``softmax(-(d - min d) / tau)`` over
    the K words, with ``d`` the squared distances computed as sums of squared differences.
    """
    codebook = np.asarray(codebook, dtype=np.float64)
    n, c, n_windows, _ = windows.shape
    n_words = codebook.shape[0]
    out = np.empty((n, c, n_words), dtype=np.float64)
    step = max(1, _CHUNK_ELEMENTS // max(1, c * n_windows * n_words * windows.shape[-1]))
    for start in range(0, n, step):
        block = np.asarray(windows[start : start + step], dtype=np.float64)
        dist = np.empty((*block.shape[:-1], n_words), dtype=np.float64)
        for k in range(n_words):
            diff = block - codebook[k]
            dist[..., k] = np.einsum("...j,...j->...", diff, diff)
        z = np.exp(-(dist - dist.min(axis=-1, keepdims=True)) / tau)
        out[start : start + step] = (z / z.sum(axis=-1, keepdims=True)).sum(axis=2)
    return out


def grouped_histograms(per_series: np.ndarray, active: np.ndarray, pad_sizes: Sequence[int], n_windows: int) -> np.ndarray:
    """Histograms ``(n, G * K)`` from per-series word weights ``(n, c, K)`` summed over ``n_windows``
    windows: active series only, divided by the group's number of active windows (zeros when none)."""
    n_cases, _, n_words = per_series.shape
    groups = channel_groups(pad_sizes)
    indicator = (groups[None, :] == np.arange(len(pad_sizes))[:, None]).astype(np.float64)  # (G, c)
    act = active.astype(np.float64)
    counts = np.einsum("gc,nck->ngk", indicator, per_series * act[:, :, None])
    totals = (act @ indicator.T) * n_windows  # (n, G)
    hist = np.where(totals[:, :, None] > 0, counts / np.maximum(totals, 1)[:, :, None], 0.0)
    return hist.reshape(n_cases, len(pad_sizes) * n_words)


def level_features(X: np.ndarray, pad_sizes: Sequence[int], fullscale: float) -> np.ndarray:
    """Per pad the mean level and the mean slope over the window, / fullscale: ``(n, 2 * G)``."""
    X = np.asarray(X, dtype=np.float64)
    groups = channel_groups(pad_sizes)
    sizes = np.asarray(pad_sizes, dtype=np.float64)
    n_t = X.shape[2]
    levels = np.stack([X[:, groups == g, :].mean(axis=(1, 2)) for g in range(len(sizes))], axis=1)
    slopes = np.stack([(X[:, groups == g, -1] - X[:, groups == g, 0]).mean(axis=1) for g in range(len(sizes))], axis=1)
    return np.concatenate([levels / fullscale, slopes / ((n_t - 1) * fullscale)], axis=1)


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

    Parameters: ``n_words`` (K), ``window`` (W, or a sequence of lengths: one codebook each),
    ``per_pad`` (one histogram per pad group, needs ``pad_sizes``: channels per pad, consecutive,
    summing to n_channels), ``max_windows`` (the k-means sample is a seeded random subset of at
    most this many windows, per scale), ``random_state``, ``assignment`` ("hard" or "soft"),
    ``temperature`` (soft only, unit-free), ``level_features``, ``fullscale`` (level features).

    Fitted: ``codebook_`` float64 ``[K, W]`` (the first scale), ``extra_codebooks_`` (the other
    scales), ``windows_``, ``temperatures_`` (absolute tau per scale), ``pad_sizes_`` tuple,
    ``level_groups_``, ``n_features_out_``, ``n_channels_``, ``n_timepoints_``,
    ``n_features_in_`` (= n_channels * n_timepoints).
    """

    def __init__(
        self,
        n_words: int = PAPER_MODEL["K"],
        window: int = PAPER_MODEL["W"],
        per_pad: bool = PAPER_MODEL["per_pad"],
        pad_sizes: Sequence[int] | None = None,
        max_windows: int = 200000,
        random_state=None,
        assignment: str = "hard",
        temperature: float = 1.0,
        level_features: bool = False,
        fullscale: float = 4095.0,
    ):
        self.n_words = n_words
        self.window = window
        self.per_pad = per_pad
        self.pad_sizes = pad_sizes
        self.max_windows = max_windows
        self.random_state = random_state
        self.assignment = assignment
        self.temperature = temperature
        self.level_features = level_features
        self.fullscale = fullscale

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

    def _window_lengths(self) -> tuple[int, ...]:
        lengths = tuple(int(w) for w in np.atleast_1d(self.window))
        if not lengths or any(w < 1 for w in lengths) or len(set(lengths)) != len(lengths):
            raise ValueError(f"window must be a length >= 1 or distinct lengths >= 1, got {self.window!r}")
        return lengths

    def _check_params(self) -> None:
        if int(self.n_words) < 1:
            raise ValueError(f"n_words must be >= 1, got {self.n_words}")
        self._window_lengths()
        if int(self.max_windows) < 1:
            raise ValueError(f"max_windows must be >= 1, got {self.max_windows}")
        if self.assignment not in ("hard", "soft"):
            raise ValueError(f"assignment must be 'hard' or 'soft', got {self.assignment!r}")
        if not float(self.temperature) > 0 or not np.isfinite(float(self.temperature)):
            raise ValueError(f"temperature must be a positive number, got {self.temperature!r}")
        if not float(self.fullscale) > 0 or not np.isfinite(float(self.fullscale)):
            raise ValueError(f"fullscale must be a positive number, got {self.fullscale!r}")

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
        lengths = self._window_lengths()
        active = active_series(X)
        rng = check_random_state(self.random_state)
        codebooks, temperatures, inertias = [], [], []
        for length in lengths:
            sample = derivative_windows(X, length)[active].reshape(-1, length)
            if len(sample) > int(self.max_windows):
                pick = np.sort(rng.choice(len(sample), size=int(self.max_windows), replace=False))
                sample = sample[pick]
            if len(sample) < int(self.n_words):
                raise ValueError(
                    f"only {len(sample)} windows of active (not all-zero) series to learn {self.n_words} words from"
                )
            kmeans = KMeans(n_clusters=int(self.n_words), n_init=KMEANS_N_INIT, random_state=rng)
            kmeans.fit(sample)
            codebooks.append(np.ascontiguousarray(kmeans.cluster_centers_, dtype=np.float64))
            inertias.append(float(kmeans.inertia_))
            spread = float(kmeans.inertia_) / len(sample)
            temperatures.append(float(self.temperature) * (spread if spread > 0 else 1.0))
        self.codebook_ = codebooks[0]
        self.extra_codebooks_ = codebooks[1:]
        self.windows_ = lengths
        self.temperatures_ = tuple(temperatures)
        self.inertia_ = inertias[0]
        self.pad_sizes_ = pad_sizes
        self.level_groups_ = tuple(int(s) for s in self.pad_sizes) if self.pad_sizes is not None else (n_channels,)
        n_levels = 2 * len(self.level_groups_) if self.level_features else 0
        self.n_features_out_ = int(self.n_words) * len(pad_sizes) * len(lengths) + n_levels
        self.n_channels_ = n_channels
        self.n_timepoints_ = n_timepoints
        self.n_features_in_ = n_channels * n_timepoints
        return self

    # -- transforming -------------------------------------------------------------------------
    def _check_X(self, X) -> np.ndarray:
        check_is_fitted(self, "codebook_")
        return check_case_shape(self, X)

    def scales(self) -> list[tuple[int, np.ndarray, float]]:
        """(window length, codebook, absolute temperature) of every scale, in feature order."""
        check_is_fitted(self, "codebook_")
        books = [self.codebook_, *getattr(self, "extra_codebooks_", [])]
        windows = getattr(self, "windows_", (int(self.codebook_.shape[1]),))
        temps = getattr(self, "temperatures_", (1.0,) * len(books))
        return list(zip(windows, books, temps, strict=True))

    def words(self, X) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per-window words, margins (runner-up minus best squared distance) and active mask.

        Returns ``words`` int64 ``(n, c, S)``, ``margins`` float64 ``(n, c, S)``, ``active`` bool
        ``(n, c)``. ``handover verify`` uses the margins to tell true near-ties from errors.
        """
        X = self._check_X(X)
        windows = derivative_windows(X, int(self.codebook_.shape[1]))
        words, margins = nearest_words(windows, self.codebook_)
        return words, margins, active_series(X)

    def transform(self, X) -> np.ndarray:
        """Normalised word histograms (one block per scale) then level features, float64
        ``(n_cases, n_features_out_)``."""
        X = self._check_X(X)
        active = active_series(X)
        parts = []
        for length, codebook, tau in self.scales():
            if self.assignment == "soft":
                windows = derivative_windows(X, length)
                sums = soft_assignment_sums(windows, codebook, tau)
                parts.append(grouped_histograms(sums, active, self.pad_sizes_, windows.shape[2]))
            else:
                parts.append(word_histograms(active_words(X, active, codebook), active, self.pad_sizes_, len(codebook)))
        if self.level_features:
            parts.append(level_features(X, self.level_groups_, float(self.fullscale)))
        return np.concatenate(parts, axis=1) if len(parts) > 1 else parts[0]

    def get_feature_names_out(self, input_features=None) -> np.ndarray:
        check_is_fitted(self, "codebook_")
        scales = self.scales()
        names = []
        for length, codebook, _ in scales:
            prefix = f"w{length}_" if len(scales) > 1 else ""
            names += [f"{prefix}pad{g}_word{k}" for g in range(len(self.pad_sizes_)) for k in range(len(codebook))]
        if self.level_features:
            n_groups = len(self.level_groups_)
            names += [f"pad{g}_level" for g in range(n_groups)] + [f"pad{g}_slope" for g in range(n_groups)]
        return np.asarray(names, dtype=object)

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.input_tags.three_d_array = True
        tags.transformer_tags.preserves_dtype = ["float64"]
        return tags
