"""Evaluation: the two configurations' splits (no subject leakage), summaries, sweeps, t-SNE."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_classifier import synthetic_series

from trainer.baseline import BaselineSVC, HandFeatures
from trainer.classifier import BowSVC
from trainer.evaluation import config1, config2, loso_splits, per_class, pooled_splits, sweep, tsne_embedding


def _grouped(n_subjects: int = 3, n_per_class: int = 6):
    Xs, ys, gs = [], [], []
    for s in range(n_subjects):
        X, y = synthetic_series(n_per_class=n_per_class, seed=s, n_channels=6, T=15)
        Xs.append(X)
        ys.append(y)
        gs.append(np.full(len(y), f"s{s + 1}"))
    return np.concatenate(Xs), np.concatenate(ys), np.concatenate(gs)


def test_loso_never_puts_a_subject_in_both_sides():
    _, y, groups = _grouped()
    splits = loso_splits(groups)
    assert [s.name for s in splits] == ["s1", "s2", "s3"]
    for s in splits:
        assert set(groups[s.test]) == {s.name}
        assert s.name not in set(groups[s.train])
        assert len(s.train) + len(s.test) == len(y)
    with pytest.raises(ValueError, match="needs a second subject"):
        loso_splits(np.array(["a", "a"]))


def test_pooled_splits_are_stratified_80_20_and_seeded():
    _, y, _ = _grouped()
    a = pooled_splits(y, seeds=[0, 1])
    assert len(a[0].test) == math.ceil(0.2 * len(y)) and not set(a[0].train) & set(a[0].test)
    for c in set(y):
        assert abs(np.sum(y[a[0].test] == c) - np.sum(y == c) * len(a[0].test) / len(y)) <= 1
    assert not np.array_equal(a[0].test, a[1].test)
    np.testing.assert_array_equal(a[0].test, pooled_splits(y, seeds=[0])[0].test)


def test_configurations_report_what_the_paper_shows():
    X, y, groups = _grouped()
    est = BowSVC(n_words=10, window=7)
    c1 = config1(est, X, y, seeds=[0, 1], n_jobs=2)
    c2 = config2(est, X, y, groups, n_jobs=2)
    assert set(c1) >= {"mean", "std", "confusion", "per_class", "split", "accuracies"}
    assert 0.0 <= c1["mean"] <= 1.0 and len(c1["accuracies"]) == 2
    assert np.sum(c1["confusion"]) == 2 * math.ceil(0.2 * len(y))
    assert set(c2["per_subject"]) == {"s1", "s2", "s3"}
    assert np.sum(c2["confusion"]) == len(y)
    assert c2["accuracy"] > 0.6  # synthetic ramps; chance is 0.25


def test_per_class_precision_recall():
    pc = per_class(np.array(["a", "a", "b", "b"]), np.array(["a", "b", "b", "b"]), ["a", "b"])
    assert pc["a"] == {"precision": 1.0, "recall": 0.5, "support": 2}
    assert pc["b"]["precision"] == pytest.approx(2 / 3)


def _make(params):
    return BowSVC(n_words=params["K"], window=params["W"], kernel=params["kernel"])


def test_sweep_runs_points_in_parallel():
    X, y, groups = _grouped(n_per_class=5)
    points = [({"K": k, "W": 4, "kernel": "linear"}, (X, y, groups)) for k in (3, 6)]
    rows = sweep(_make, points, mode="loso")
    assert [r["K"] for r in rows] == [3, 6] and all(0 <= r["accuracy"] <= 1 for r in rows)


def test_baseline_features_and_classifier():
    X, y, _ = _grouped(n_per_class=5)
    feats = HandFeatures(pad_shapes=[(2, 2), (1, 2)]).fit(X)
    F = feats.transform(X)
    assert F.shape == (len(X), 28) and np.all(np.isfinite(F))
    assert feats.get_feature_names_out()[0] == "pad0_max"
    clf = BaselineSVC(pad_shapes=[(3, 2)]).fit(X, y)
    assert clf.score(X, y) > 0.5
    with pytest.raises(ValueError, match="cover 3 taxels"):
        HandFeatures(pad_shapes=[(1, 3)]).fit(X)


def test_centre_of_pressure_by_hand():
    X = np.zeros((1, 6, 3))
    X[0, 0, :] = [1, 1, 0]  # taxel (row 0, col 0)
    X[0, 5, :] = [0, 1, 1]  # taxel (row 1, col 2) on a 2 x 3 pad
    F = HandFeatures(pad_shapes=[(2, 3)]).fit(X).transform(X)[0]
    names = list(HandFeatures(pad_shapes=[(2, 3)]).fit(X).get_feature_names_out())
    got = dict(zip(names, F, strict=True))
    assert got["pad0_cop_x"] == pytest.approx((0 + 1 + 2) / 3)
    assert got["pad0_cop_dx"] == pytest.approx(2.0) and got["pad0_cop_dy"] == pytest.approx(1.0)


def test_tsne_gives_two_columns():
    X, y, _ = _grouped(n_subjects=1, n_per_class=5)
    H = BowSVC(n_words=5, window=4).fit(X, y).transform_histograms(X)
    emb = tsne_embedding(H, seed=0)
    assert emb.shape == (len(X), 2)


@pytest.mark.parametrize("rows", ["identical", "zeros"])
def test_tsne_of_cases_without_spread_is_points_not_a_segfault(rows):
    """Identical training cases (a recording whose trials are one and the same step) made
    sklearn's t-SNE divide by a zero spread and the whole ``handover train`` die of SIGSEGV."""
    import subprocess
    import sys

    fill = "np.ones((40, 20)) * 0.3" if rows == "identical" else "np.zeros((40, 20))"
    code = ("import numpy as np\nfrom trainer.evaluation import tsne_embedding\n"
            f"e = tsne_embedding({fill})\nassert e.shape == (40, 2) and np.isfinite(e).all(), e\nprint('ok')")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "ok", (done.returncode, done.stderr[-500:])


def test_rbf_decision_bound_far_from_every_support_vector_is_inf_not_nan():
    """A case far from every support vector with a large input error (a model trained on cases
    without spread: the scaler blows the error up) gave kernel 0 x expm1 overflow = NaN, so
    ``handover verify`` printed 'SVM margin nan' and called an exact tie 'NOT a near tie'."""
    from sklearn.svm import SVC

    from trainer.numerics import svm_decision_bounds

    svm = SVC(kernel="rbf", gamma=1.0).fit(np.array([[0.0], [1.0], [2.0]]), np.array([0, 1, 2]))  # zero coefs too
    with np.errstate(all="ignore"):
        bound = svm_decision_bounds(svm, np.array([[100.0]]), np.array([[100.0]]))
    assert not np.isnan(bound).any() and (bound > 0).all(), bound
