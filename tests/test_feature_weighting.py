"""Feature weighting (trainer.feature_weighting): the weights do what each rule says, are folded into
the scaler of FeatureSVC, and the ONE ONNX graph still agrees with its float64 reference."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.preprocessing import StandardScaler

from tests.onnx_fixtures import PAD_SIZES, T, export, frames_of, synthetic_cases
from trainer.baseline import FEATURES_PER_PAD
from trainer.feature_svc import FeatureSVC
from trainer.feature_weighting import feature_weights
from trainer.stress import stress_cases
from trainer.verify import GraphRunner, compare


def _standardised(n: int = 200, n_features: int = 8, seed: int = 0) -> np.ndarray:
    return StandardScaler().fit_transform(np.random.default_rng(seed).normal(size=(n, n_features)))


def test_block_count_gives_every_block_unit_total_variance():
    Z = _standardised(n_features=8)
    Z[:, 3] = 0.0  # a constant feature counts for nothing
    w = feature_weights(Z, [2, 6], "block_count")
    assert np.allclose(w[:2], 1 / np.sqrt(2)) and np.allclose(w[2:], 1 / np.sqrt(5))
    total = [((Z * w)[:, a:b] ** 2).mean(axis=0).sum() for a, b in ((0, 2), (2, 8))]
    assert np.allclose(total, 1.0)


def test_block_mfa_gives_every_block_a_unit_first_eigenvalue():
    Z = _standardised(n_features=6)
    Z[:, 1:4] = Z[:, [0]]  # block 0: four copies of one quantity (first eigenvalue 4)
    w = feature_weights(Z, [4, 2], "block_mfa")
    assert np.allclose(w[:4], 0.5)
    for a, b in ((0, 4), (4, 6)):
        assert np.isclose(np.linalg.eigvalsh(np.cov((Z * w)[:, a:b], rowvar=False, bias=True)).max(), 1.0)


def test_distinct_counts_a_duplicated_quantity_once():
    Z = _standardised(n_features=5)
    Z[:, 3] = -Z[:, 0]  # the same quantity, of opposite sign (standardised: an affine copy)
    Z[:, 4] = Z[:, 0]
    w = feature_weights(Z, [2, 3], "distinct")
    assert np.allclose(w[[0, 3, 4]], 1 / np.sqrt(3)) and np.allclose(w[[1, 2]], 1.0)
    # squared distances are those of the features without the copies
    d_weighted = ((Z[:1] * w - Z[1:] * w) ** 2).sum(axis=1)
    d_unique = ((Z[:1, :3] - Z[1:, :3]) ** 2).sum(axis=1)
    assert np.allclose(d_weighted, d_unique)


def test_unknown_weighting_and_bad_sizes_are_refused():
    Z = _standardised()
    with pytest.raises(ValueError, match="feature_weighting must be one of"):
        feature_weights(Z, [8], "equal")
    with pytest.raises(ValueError, match="must sum to"):
        feature_weights(Z, [3, 3], "block_count")
    X, y = synthetic_cases(n=24, seed=1)
    with pytest.raises(ValueError, match="feature_weighting must be one of"):
        FeatureSVC(families=("stats",), pad_sizes=PAD_SIZES, feature_weighting="equal").fit(X, y)


@pytest.fixture(scope="module")
def cases():
    return synthetic_cases(n=72, seed=3)


def test_off_by_default_leaves_the_scaler_alone(cases):
    X, y = cases
    model = FeatureSVC(families=("hand", "stats"), pad_sizes=PAD_SIZES, C=10.0, gamma="scale").fit(X, y)
    plain = StandardScaler().fit(model.transform_histograms(X))
    assert model.feature_weighting is None and np.array_equal(model.scaler_.scale_, plain.scale_)
    assert "feature_weighting" not in model.describe()


@pytest.mark.parametrize("weighting", ["distinct", "block_mfa"])
def test_weights_fold_into_the_scaler_and_the_graph_agrees(weighting, cases, tmp_path):
    X, y = cases
    model = FeatureSVC(families=("hand", "stats"), pad_sizes=PAD_SIZES, C=10.0, gamma="scale",
                       feature_weighting=weighting).fit(X, y)
    hist = model.transform_histograms(X)
    plain = StandardScaler().fit(hist)
    n_hand = len(FEATURES_PER_PAD) * len(PAD_SIZES)
    w = feature_weights(plain.transform(hist), [n_hand, hist.shape[1] - n_hand], weighting)
    assert np.allclose(model.svm_input(hist), plain.transform(hist) * w)
    if weighting == "distinct":  # the hand family's pad maximum is the stats family's peak (x fullscale)
        peak = n_hand + 3 * 4 * len(PAD_SIZES)
        assert np.allclose(w[[0, len(FEATURES_PER_PAD), peak, peak + 1]], 1 / np.sqrt(2))
    path = export(model, tmp_path)
    runner = GraphRunner(path)
    report = compare(model, runner, frames_of(X), ["train"] * len(X))
    stress = stress_cases(T, sum(PAD_SIZES), np.eye(2, 4) * 100.0, seed=1)
    report = compare(model, runner, np.concatenate(list(stress.values())),
                     [f"stress:{k}" for k, v in stress.items() for _ in v], report=report)
    assert report.ok and report.unexplained_disagreements == 0, report.to_dict()
    labels, _, _ = runner.run(frames_of(X))
    assert np.array_equal(model.classes_[labels], model.predict(X))
