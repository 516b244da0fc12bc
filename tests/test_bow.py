"""BagOfWords: the float64 reference arithmetic on hand-computed cases, the all-zero rule, per-pad groups."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.base import clone

from trainer.bow import BagOfWords, active_series, derivative_windows, nearest_words


def _fitted(codebook, n_channels: int, n_timepoints: int, **kw) -> BagOfWords:
    """A BagOfWords fitted on noise, then given a hand-written codebook."""
    codebook = np.asarray(codebook, dtype=np.float64)
    rng = np.random.default_rng(0)
    X = rng.integers(1, 50, size=(8, n_channels, n_timepoints)).astype(float)
    bow = BagOfWords(n_words=len(codebook), window=codebook.shape[1], random_state=0, **kw).fit(X)
    bow.codebook_ = codebook
    return bow


def test_derivative_and_windows_by_hand():
    X = np.array([[[0, 1, 3, 6, 10]]], dtype=float)
    win = derivative_windows(X, 2)
    assert win.shape == (1, 1, 3, 2)
    np.testing.assert_array_equal(win[0, 0], [[1, 2], [2, 3], [3, 4]])
    # W = T-1 is the largest window: exactly one
    np.testing.assert_array_equal(derivative_windows(X, 4)[0, 0], [[1, 2, 3, 4]])
    with pytest.raises(ValueError, match="W=5 needs at least"):
        derivative_windows(X, 5)


def test_nearest_word_ties_go_to_lowest_index_and_margins():
    codebook = np.array([[1.0, 2.0], [3.0, 4.0]])
    windows = np.array([[1.0, 2.0], [2.0, 3.0], [3.0, 4.0], [10.0, 10.0]])
    words, margins = nearest_words(windows, codebook)
    np.testing.assert_array_equal(words, [0, 0, 1, 1])
    # [2,3] is 2 from both words: a true tie, margin 0
    np.testing.assert_allclose(margins, [8.0, 0.0, 8.0, (81 + 64) - (49 + 36)])


def test_histogram_by_hand_and_the_all_zero_rule():
    bow = _fitted([[1.0, 2.0], [3.0, 4.0]], n_channels=2, n_timepoints=5)
    X = np.array(
        [
            [[0, 1, 3, 6, 10], [0, 0, 0, 0, 0]],  # channel 1 all zero: left out
            [[0, 0, 0, 0, 0], [0, 0, 0, 0, 0]],  # nothing active: all-zero histogram
            [[5, 5, 5, 5, 5], [0, 1, 3, 6, 10]],  # constant but non-zero: active, derivative 0
        ],
        dtype=float,
    )
    H = bow.transform(X)
    np.testing.assert_allclose(H[0], [2 / 3, 1 / 3])
    np.testing.assert_array_equal(H[1], [0.0, 0.0])
    # case 2: channel 0 windows are [0,0] x3 -> word 0; channel 1 as case 0 -> 2x word 0, 1x word 1
    np.testing.assert_allclose(H[2], [5 / 6, 1 / 6])
    np.testing.assert_array_equal(active_series(X), [[True, False], [False, False], [True, True]])


def test_per_pad_histograms_are_normalised_per_group():
    bow = _fitted([[1.0, 2.0], [3.0, 4.0]], n_channels=3, n_timepoints=5, per_pad=True, pad_sizes=(2, 1))
    X = np.array([[[0, 1, 3, 6, 10], [0, 0, 0, 0, 0], [0, 3, 7, 11, 15]]], dtype=float)
    H = bow.transform(X)
    assert bow.n_features_out_ == 4 and bow.pad_sizes_ == (2, 1)
    np.testing.assert_allclose(H[0], [2 / 3, 1 / 3, 0.0, 1.0])


def test_not_per_pad_means_one_group():
    bow = _fitted([[1.0, 2.0]], n_channels=3, n_timepoints=4)
    assert bow.pad_sizes_ == (3,) and bow.n_features_out_ == 1


def test_per_pad_needs_sizes_that_add_up():
    X = np.ones((4, 3, 9))
    with pytest.raises(ValueError, match="needs pad_sizes"):
        BagOfWords(n_words=2, window=3, per_pad=True).fit(X)
    with pytest.raises(ValueError, match="sum to n_channels=3"):
        BagOfWords(n_words=2, window=3, per_pad=True, pad_sizes=(2, 2)).fit(X)


def test_codebook_contract_and_determinism():
    rng = np.random.default_rng(1)
    X = rng.integers(0, 4095, size=(20, 6, 15)).astype(np.float32)
    X[:, 0, :] = 0
    a = BagOfWords(n_words=10, window=7, random_state=3, max_windows=500).fit(X)
    b = clone(a).fit(X)
    assert a.codebook_.dtype == np.float64 and a.codebook_.shape == (10, 7)
    np.testing.assert_array_equal(a.codebook_, b.codebook_)
    np.testing.assert_array_equal(a.transform(X), b.transform(X))
    np.testing.assert_allclose(a.transform(X).sum(axis=1), 1.0)


def test_all_zero_series_do_not_reach_the_codebook():
    """Only active series train k-means: zeros would otherwise pull a word to the origin."""
    X = np.zeros((10, 5, 10))
    X[:, 0, :] = np.arange(10) * 3.0  # derivative 3 everywhere
    bow = BagOfWords(n_words=1, window=4, random_state=0).fit(X)
    np.testing.assert_allclose(bow.codebook_, [[3.0, 3.0, 3.0, 3.0]])


def test_too_few_windows_is_a_clear_error():
    X = np.zeros((3, 2, 5))
    with pytest.raises(ValueError, match="only 0 windows"):
        BagOfWords(n_words=2, window=2).fit(X)


def test_transform_checks_the_shape_it_was_fitted_on():
    bow = _fitted([[1.0, 2.0]], n_channels=2, n_timepoints=5)
    with pytest.raises(ValueError, match="expecting 10 features"):
        bow.transform(np.ones((1, 2, 6)))


def test_two_d_input_is_one_channel():
    rng = np.random.default_rng(2)
    X2 = rng.normal(size=(12, 9))
    a = BagOfWords(n_words=3, window=3, random_state=0).fit(X2)
    b = BagOfWords(n_words=3, window=3, random_state=0).fit(X2[:, None, :])
    np.testing.assert_array_equal(a.transform(X2), b.transform(X2[:, None, :]))


def test_histograms_read_the_words_of_active_series_alone():
    """transform finds words for the active series only (most taxels of a window are untouched): the same
    histograms as every series' words weighted by the all-zero rule."""
    from trainer.bow import active_words, as_cases, word_histograms

    rng = np.random.default_rng(1)
    X = rng.integers(0, 300, size=(30, 12, 9)).astype(float)
    X[rng.random((30, 12)) < 0.7] = 0.0
    bow = BagOfWords(n_words=4, window=3, per_pad=True, pad_sizes=(6, 6), random_state=0).fit(X)
    active = active_series(as_cases(X))
    every, _ = nearest_words(derivative_windows(X, 3), bow.codebook_)
    assert not active.all() and active.any()
    np.testing.assert_array_equal(active_words(X, active, bow.codebook_)[active], every[active])
    np.testing.assert_array_equal(bow.transform(X), word_histograms(every, active, (6, 6), 4))
    assert nearest_words(derivative_windows(X, 3), bow.codebook_, margins=False)[1] is None
