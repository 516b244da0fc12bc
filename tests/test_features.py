"""Richer features (multi-scale codebooks, soft assignment, level features, scaling) and the
flattened-series SVM: shapes, reference arithmetic by hand, determinism, and parity of the one
ONNX graph with the float64 reference (only near ties may differ, never NaN/inf)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from sklearn.base import clone
from sklearn.utils.estimator_checks import parametrize_with_checks

from runtime.model import load_model
from tests.onnx_fixtures import PAD_SIZES, T, check_report, export, frames_of, synthetic_cases
from trainer.bow import BagOfWords, level_features
from trainer.classifier import BowSVC
from trainer.flat import FlatSVC
from trainer.stress import stress_cases
from trainer.verify import GraphRunner, compare

C = sum(PAD_SIZES)

OPTIONS = {
    "multiscale": {"window": (3, 5, 7)},
    "soft": {"assignment": "soft", "temperature": 1.0},
    "soft_cold": {"assignment": "soft", "temperature": 0.05},
    "levels": {"level_features": True},
    "levels_scaled": {"level_features": True, "scale_features": True},
    "all": {"window": (3, 6), "assignment": "soft", "level_features": True, "scale_features": True, "n_words": 12},
    "all_linear": {"window": (4, 6), "level_features": True, "scale_features": True, "kernel": "linear"},
}


def fit_option(name: str, seed: int = 0) -> BowSVC:
    X, y = synthetic_cases(seed=seed)
    kw = {"n_words": 6, "window": 5, "per_pad": True, "pad_sizes": PAD_SIZES, "C": 10.0, "gamma": "scale", **OPTIONS[name]}
    if kw.get("kernel") == "linear":
        kw.pop("gamma")
    return BowSVC(**kw).fit(X, y)


FAST_OPTIONS = ("multiscale", "all", "all_linear")
"""Default run: these cover every option (multi-scale, soft, levels, scaling, both kernels); the
single-option models run with ``-m slow``."""


@pytest.fixture(scope="module", params=[n if n in FAST_OPTIONS else pytest.param(n, marks=pytest.mark.slow)
                                        for n in OPTIONS])
def exported(request, tmp_path_factory):
    model = fit_option(request.param)
    return request.param, model, GraphRunner(export(model, tmp_path_factory.mktemp(request.param)))


def test_paper_defaults_unchanged():
    p = BowSVC().get_params()
    assert (p["n_words"], p["window"], p["per_pad"], p["assignment"], p["level_features"], p["scale_features"]) == (
        10, 7, False, "hard", False, False)
    assert BagOfWords().get_params()["assignment"] == "hard"


def test_shapes_and_names():
    X, _ = synthetic_cases(n=40)
    bow = BagOfWords(n_words=4, window=(3, 5), per_pad=True, pad_sizes=PAD_SIZES, level_features=True,
                     random_state=0).fit(X)
    H = bow.transform(X)
    assert bow.n_features_out_ == 2 * 2 * 4 + 2 * 2 == H.shape[1]
    assert bow.codebook_.shape == (4, 3) and bow.extra_codebooks_[0].shape == (4, 5)
    names = bow.get_feature_names_out()
    assert names[0] == "w3_pad0_word0" and names[8] == "w5_pad0_word0" and list(names[-4:]) == [
        "pad0_level", "pad1_level", "pad0_slope", "pad1_slope"]
    # each scale's histogram of each active pad sums to 1
    for block in range(4):
        sums = H[:, block * 4 : block * 4 + 4].sum(axis=1)
        assert np.all((np.abs(sums - 1) < 1e-12) | (sums == 0))


def test_soft_histograms_sum_to_one_and_approach_hard_when_cold():
    X, _ = synthetic_cases(n=30)
    hard = BagOfWords(n_words=5, window=4, random_state=0).fit(X)
    soft = BagOfWords(n_words=5, window=4, random_state=0, assignment="soft", temperature=1.0).fit(X)
    cold = BagOfWords(n_words=5, window=4, random_state=0, assignment="soft", temperature=1e-6).fit(X)
    np.testing.assert_array_equal(soft.codebook_, hard.codebook_)  # assignment does not change k-means
    np.testing.assert_allclose(soft.transform(X).sum(axis=1), 1.0)
    np.testing.assert_allclose(cold.transform(X), hard.transform(X), atol=1e-9)
    assert np.abs(soft.transform(X) - hard.transform(X)).max() > 0.01


def test_soft_by_hand():
    X = np.array([[[0.0, 1.0, 3.0]]])  # one window of the derivative: [1, 2]
    bow = BagOfWords(n_words=1, window=2, random_state=0, assignment="soft").fit(np.ones((3, 1, 3)) * np.arange(3))
    bow.codebook_ = np.array([[1.0, 2.0]])
    bow.extra_codebooks_ = []
    bow.temperatures_ = (2.0,)
    np.testing.assert_allclose(bow.transform(X), [[1.0]])
    bow.n_words, bow.codebook_ = 2, np.array([[1.0, 2.0], [1.0, 4.0]])  # d = 0 and 4: weights e^0, e^-2
    np.testing.assert_allclose(bow.transform(X)[0], [1 / (1 + np.exp(-2)), np.exp(-2) / (1 + np.exp(-2))])


def test_level_features_by_hand():
    X = np.array([[[0.0, 4095.0], [4095.0, 4095.0], [0.0, 0.0]]])  # 3 channels, T = 2
    np.testing.assert_allclose(level_features(X, (2, 1), 4095.0), [[0.75, 0.0, 0.5, 0.0]])


def test_bad_options_are_refused():
    X, y = synthetic_cases(n=20)
    for kw, msg in (({"assignment": "fuzzy"}, "assignment"), ({"temperature": 0.0}, "temperature"),
                    ({"window": (3, 3)}, "distinct"), ({"window": (3, 40)}, "W=40 needs")):
        with pytest.raises(ValueError, match=msg):
            BowSVC(n_words=3, **kw).fit(X, y)


@pytest.mark.parametrize("name", ["multiscale", "all"])
def test_determinism(name):
    a = fit_option(name)
    b = clone(a).fit(*synthetic_cases())
    Xt, _ = synthetic_cases(n=32, seed=5)
    np.testing.assert_array_equal(a.decision_function(Xt), b.decision_function(Xt))
    for (_, ca, _), (_, cb, _) in zip(a.bow_.scales(), b.bow_.scales(), strict=True):
        np.testing.assert_array_equal(ca, cb)


def test_graph_parity_on_cases_and_stress(exported):
    name, model, runner = exported
    X, _ = synthetic_cases(n=64, seed=7)
    families = stress_cases(T, C, model.bow_.codebook_, seed=1)
    stress = np.concatenate(list(families.values()))
    report = compare(model, runner, np.concatenate([frames_of(X), stress]), ["sim"] * 64 + ["stress"] * len(stress))
    check_report(report)
    assert report.by_source["sim"]["agree"] >= 62  # synthetic; near ties are rare
    _labels, _scores, hist = runner.run(frames_of(X))
    assert hist.shape == (64, model.bow_.n_features_out_)
    ref_hist = model.transform_histograms(X)
    tol = 2e-3 if model.bow_.assignment == "soft" else 1e-6
    clear = np.abs(hist - ref_hist).max(axis=1) < tol
    assert clear.mean() > 0.9, name


def test_metadata_describes_the_features(exported, tmp_path):
    _name, model, runner = exported
    meta = load_model(runner.path).meta
    feats = meta.extra["features"]
    assert feats["windows"] == [w for w, _, _ in model.bow_.scales()] and max(feats["windows"]) == meta.W
    assert feats["assignment"] == model.bow_.assignment and feats["n_features"] == model.bow_.n_features_out_
    assert feats["scale_features"] == bool(model.scale_features)
    assert meta.extra["model_kind"] == "bow_svm"


window_values = st.one_of(st.sampled_from([0.0, 1.0, 4095.0]), st.integers(0, 4095).map(float),
                          st.floats(-1e5, 1e5, allow_nan=False, width=32))


@pytest.fixture(scope="module")
def soft_all(tmp_path_factory):
    model = fit_option("all")
    return model, GraphRunner(export(model, tmp_path_factory.mktemp("soft_all")))


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(arrays(np.float32, (2, T, C), elements=window_values))
def test_random_windows_soft_levels_scaled(soft_all, frames):
    model, runner = soft_all
    check_report(compare(model, runner, frames, ["hypothesis"] * 2))


@pytest.mark.slow
@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(arrays(np.float32, (2, T, C), elements=window_values))
def test_random_windows_soft_levels_scaled_thorough(soft_all, frames):
    model, runner = soft_all
    check_report(compare(model, runner, frames, ["hypothesis"] * 2))


# -- flattened-series SVM -------------------------------------------------------------------------
# With a given C the checks skip the grid search, whose hardest margins (C up to 1e6) take libsvm
# seconds per fit on the checks' random data; the searching instance runs with -m slow.
@parametrize_with_checks([FlatSVC(C=10.0)])
def test_flat_estimator_checks(estimator, check):
    check(estimator)


@pytest.mark.slow
@parametrize_with_checks([FlatSVC()])
def test_flat_estimator_checks_with_search(estimator, check):
    check(estimator)


@pytest.mark.parametrize("kernel", ["rbf", "linear"])
def test_flat_svm_graph_parity(kernel, tmp_path):
    X, y = synthetic_cases(seed=0)
    model = FlatSVC(kernel=kernel, C=10.0).fit(X, y)
    path = export(model, tmp_path)
    meta = load_model(path).meta
    assert meta.extra["model_kind"] == "flat_svm" and (meta.T, meta.n_channels) == (T, C)
    Xt, _ = synthetic_cases(n=64, seed=3)
    runner = GraphRunner(path)
    stress = np.concatenate(list(stress_cases(T, C, np.eye(3, 5), seed=2).values()))
    report = compare(model, runner, np.concatenate([frames_of(Xt), stress]), ["sim"] * 64 + ["stress"] * len(stress))
    check_report(report)
    labels, _, hist = runner.run(frames_of(Xt))
    np.testing.assert_array_equal(hist, Xt.reshape(64, -1))
    assert np.mean(labels == np.searchsorted(model.classes_, model.predict(Xt))) >= 0.98


def test_verify_accepts_a_flat_svm_reference(tmp_path, capsys):
    """load_trained takes any fitted model with svm_ and classes_ (bare or with metadata): verify runs."""
    import joblib

    from runtime.cli import main as handover
    from trainer.trained_file import export_trained, load_trained

    X, y = synthetic_cases(seed=0)
    model = FlatSVC(kernel="linear", C=10.0).fit(X, y)
    joblib.dump(model, tmp_path / "bare.joblib")
    assert isinstance(load_trained(tmp_path / "bare.joblib")[0], FlatSVC)
    joblib.dump({"model": model, "metadata": {"pads": [1, 3], "pad_sizes": list(PAD_SIZES),
                 "training": {"data_fingerprint": "synthetic", "n_trials": 96}}}, tmp_path / "flat.joblib")
    path = export_trained(tmp_path / "flat.joblib", tmp_path / "flat.onnx")
    assert handover(["verify", str(path), "--no-trials"]) == 0, capsys.readouterr()
    lines = capsys.readouterr().out.splitlines()  # the verdict first, then what the figures mean
    assert lines[0].startswith(f"verify {path}: PASSED: the graph gives the float64 reference's label on "), lines
    assert any(line.startswith("  near ties (not failures") for line in lines)
