"""Feature families beyond the paper (level statistics, MiniRocket-style Conv PPV, the hand-designed
baseline, their mixes with BoW): each ONE ONNX graph agrees with its float64 reference on small
synthetic cases and on the stress families; the default estimator; --select; one real task."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.utils.estimator_checks import parametrize_with_checks

from runtime.model import load_model
from tests.conftest import real_data_dir
from tests.onnx_fixtures import PAD_SIZES, T, export, frames_of, synthetic_cases
from trainer.feature_svc import FeatureSVC
from trainer.features import ContactImage, HandGraphFeatures, PadStats, RandomConvPPV
from trainer.features.signals import pad_shapes_for, pad_signals
from trainer.numerics import SAFETY
from trainer.stress import stress_cases
from trainer.verify import GraphRunner, compare

C = sum(PAD_SIZES)
FAMILY_MIXES = [("stats",), ("rocket",), ("hand",), ("image",), ("stats", "bow"), ("hand", "stats", "image"),
                ("rocket", "stats", "hand", "bow")]


@pytest.fixture(scope="module")
def cases():
    return synthetic_cases(n=72, seed=3)


@pytest.mark.parametrize("families", FAMILY_MIXES, ids="+".join)
def test_graph_agrees_with_the_float64_reference(families, cases, tmp_path):
    X, y = cases
    model = FeatureSVC(families=families, pad_sizes=PAD_SIZES, kernel="rbf", C=10.0, gamma="scale",
                       n_words=5, window=4).fit(X, y)
    path = export(model, tmp_path)
    meta = load_model(path).meta
    assert meta.extra["model_kind"] == "feature_svm" and meta.extra["features"]["families"] == list(families)
    runner = GraphRunner(path)
    report = compare(model, runner, frames_of(X), ["train"] * len(X))
    stress = stress_cases(T, C, np.eye(2, 4) * 100.0, seed=1)
    frames = np.concatenate(list(stress.values()))
    report = compare(model, runner, frames, [f"stress:{k}" for k, v in stress.items() for _ in v], report=report)
    assert report.ok, report.to_dict()
    assert report.nan_or_inf_outputs == 0 and report.unexplained_disagreements == 0
    assert report.by_source["train"]["agree"] == len(X)
    # the graph's labels are the reference's on the training cases, and its features are close
    labels, _, hist = runner.run(frames_of(X))
    assert np.array_equal(model.classes_[labels], model.predict(X))
    ref = model.transform_histograms(X)
    bound = 1e-6 + SAFETY * model.feature_error_bounds(X) + 1e-6 * np.abs(ref)
    if "bow" in families:  # hard words: only windows at a near tie may move (checked by compare above)
        bound[:, model.bow_slice_] = 1.0
    assert np.all(np.abs(hist - ref) <= bound)


def test_signals_by_hand():
    X = np.zeros((1, 12, 3))
    X[0, 0, :] = 4095.0  # pad 0 (2 x 6): the top-left taxel at full scale
    s = pad_signals(X, pad_shapes_for([12]), 4095.0)  # (1, 4, 3): pressure, area, cx, cy
    assert np.allclose(s[0, 0], 1 / 12) and np.allclose(s[0, 1], 1 / 12)
    # centre of pressure damped by one full-scale taxel: x = -2.5/6 * 4095 / (4095 + 4095)
    assert np.allclose(s[0, 2], -2.5 / 6 / 2) and np.allclose(s[0, 3], -0.5 / 2 / 2)
    assert pad_shapes_for([78, 84, 5]) == [(13, 6), (14, 6), (1, 5)]


def test_pad_stats_mean_std_change_peak():
    X = np.zeros((1, 6, 4))
    X[0, :, :] = np.array([0.0, 1.0, 2.0, 3.0]) * 1000.0
    f = PadStats(pad_sizes=(6,)).fit(X).transform(X)[0]
    assert f.shape == (13,)
    pressure = np.arange(4) * 1000.0 / 4095.0
    assert np.isclose(f[0], pressure.mean()) and np.isclose(f[4], pressure.std())
    assert np.isclose(f[8], pressure[-1]) and np.isclose(f[12], 3000.0 / 4095.0)


@pytest.mark.parametrize("sizes", [(0, 78, 156), (-1, 79, 156), (77.5, 78.5, 78)])
def test_pad_sizes_must_be_positive(sizes):
    X = np.zeros((4, 234, 15))
    with pytest.raises(ValueError, match="all positive"):
        PadStats(pad_sizes=sizes).fit(X)


def test_contact_image_is_each_taxels_mean():
    X = np.zeros((2, 6, 4))
    X[0, 2, :] = [0.0, 4095.0, 4095.0, 0.0]
    X[1, 5, :] = 4095.0
    f = ContactImage(pad_sizes=(6,)).fit(X).transform(X)
    assert f.shape == (2, 6) and np.allclose(f[0], [0, 0, 0.5, 0, 0, 0]) and np.allclose(f[1], [0, 0, 0, 0, 0, 1])
    assert list(ContactImage().fit(X).get_feature_names_out()[:2]) == ["taxel0_mean", "taxel1_mean"]


def test_rocket_kernels_and_biases():
    from trainer.features.rocket import minirocket_kernels

    k = minirocket_kernels()
    assert k.shape == (84, 9) and np.all(k.sum(axis=1) == 0) and len({tuple(r) for r in k}) == 84
    X, _ = synthetic_cases(n=40, seed=1)
    fam = RandomConvPPV(dilations=(1, 2), n_biases=2, pad_sizes=PAD_SIZES).fit(X)
    F = fam.transform(X)
    assert F.shape == (40, 2 * 84 * 2 * 4 * 2) and F.min() >= 0 and F.max() <= 1
    assert np.array_equal(F, RandomConvPPV(dilations=(1, 2), n_biases=2, pad_sizes=PAD_SIZES).fit(X).transform(X))


def test_hand_family_is_the_baseline_features(cases):
    from trainer.baseline import HandFeatures

    X, _ = cases
    shapes = pad_shapes_for(PAD_SIZES)
    assert np.allclose(HandGraphFeatures(pad_sizes=PAD_SIZES).fit(X).transform(X),
                       HandFeatures(shapes).fit(X).transform(X))


@parametrize_with_checks([FeatureSVC(families=("stats",), kernel="rbf", C=10.0, gamma="scale")])
def test_feature_svc_estimator_checks(estimator, check):
    check(estimator)


@pytest.mark.parametrize("n_frames", [12, 40])
def test_default_classifier_fits_and_predicts(n_frames):
    from trainer import default_classifier

    rng = np.random.default_rng(0)
    y = np.repeat(["pull", "push", "hold"], 8)
    X = rng.integers(0, 200, (24, 3 * 12, n_frames)).astype(float)
    X[y == "pull", :12] += np.linspace(0, 3000, n_frames)  # pad 0 rises
    X[y == "push", 12:24] += 2500.0  # pad 1 pressed
    model = default_classifier([12, 12, 12])
    assert model.get_params()["pad_sizes"] == (12, 12, 12)
    model.fit(X, y)
    assert model.predict(X).shape == (24,) and np.mean(model.predict(X) == y) > 0.9


def test_select_chooses_within_the_budget_and_reports_runners_up():
    import tempfile
    from dataclasses import replace
    from pathlib import Path

    from tests.protocol_standin import write_standin
    from trainer.dataset import build_dataset
    from trainer.select import markdown_lines, select_model
    from trainer.train_options import TrainOptions

    with tempfile.TemporaryDirectory() as tmp:
        write_standin(Path(tmp), n_subjects=3, runs=2, silent=0)
        from firmware_io.recordings.recording import find_recordings, load_all

        ds = build_dataset(load_all(find_recordings(tmp)), T=12, pads="distal")
    options = TrainOptions(K=5, W=4)
    candidates = (("stats rbf", ("stats",), "rbf", {}), ("stats+bow rbf", ("stats", "bow"), "rbf", {}))
    sel = select_model(ds, options, candidates=candidates)
    assert sel.split == "leave one subject out" and {r.name for r in sel.rows} == {"stats rbf", "stats+bow rbf"}
    assert all(len(r.fold_accuracies) == 3 and r.p99_us > 0 for r in sel.rows)
    tied = [r for r in sel.rows if r.ties_best and r.within_budget]
    winner = min(tied, key=lambda r: r.p50_us)  # the best and its ties (one standard error): the fastest
    assert sel.winner == winner.name == sel.rows[0].name and sel.estimator.families == winner.families
    assert any("(winner)" in line for line in markdown_lines(sel))
    # a budget nothing meets: the rule still names the most accurate, and says none is within it
    sel = select_model(ds, replace(options, latency_budget_us=0.001), candidates=candidates)
    assert not any(r.within_budget for r in sel.rows)


def test_select_ranks_like_the_default_rule():
    from trainer.select import Row, rank

    def row(name, folds, p50, within=True):
        return Row(name, (), "rbf", {}, folds, float(np.mean(list(folds.values()))), 0.0, p50, p50, within)

    best = row("best", {"s1": 0.90, "s2": 0.80, "s3": 0.85}, 200.0)
    noisy = row("noisy", {"s1": 0.95, "s2": 0.70, "s3": 0.88}, 50.0)  # 0.7 points lower, differences +5/-10/+3
    steady = row("steady", {"s1": 0.89, "s2": 0.79, "s3": 0.84}, 20.0)  # 1 point lower on every fold
    slow = row("slow", {"s1": 0.99, "s2": 0.99, "s3": 0.99}, 5000.0, within=False)
    rows = [best, noisy, steady, slow]
    assert rank(rows) is noisy and [r.name for r in rows] == ["noisy", "best", "steady", "slow"]


@pytest.mark.realdata
def test_default_beats_chance_clearly_on_real_objects():
    from trainer.defaults import default_classifier
    from trainer.real_tasks import grouped_task

    video = real_data_dir() / "kiechle" / "pressure_profiles" / "classification_video"
    paths = {p.stem: p for p in sorted(video.glob("*.dsa"))}
    task = grouped_task("real_objects", "test", paths, (1, 3, 5), seed=0)
    split = task.splits[0]
    assert not set(task.chunks[split.train]) & set(task.chunks[split.test])  # chunks never straddle
    model = default_classifier(task.pad_sizes, pad_shapes=task.pad_shapes).fit(task.X[split.train], task.y[split.train])
    acc = np.mean(model.predict(task.X[split.test]) == task.y[split.test])
    assert acc > 3 / len(paths)  # 7 objects: chance is 14 %; the compare reports the full figure


def _held_grasp_cases(n: int = 40, seed: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Cases like real SDH-2 holds: integer taxels up to full scale, a pad that is all zero, pads that
    hold still (a near-constant mean signal) and pads that press a single taxel lightly."""
    rng = np.random.default_rng(seed)
    X = np.zeros((n, C, T))
    y = np.arange(n) % 2
    for i in range(n):
        level = rng.uniform(200, 4095)
        X[i, :6] = np.round(level * rng.uniform(0.5, 1, (6, 1)) + rng.normal(0, 3 + 40 * y[i], (6, T)))
        if i % 3 == 0:
            X[i, 6 + rng.integers(10)] = rng.integers(1, 4)  # one light taxel on the second pad
    return np.clip(X, 0, 4095), y


def test_hand_bounds_are_at_each_features_own_scale(tmp_path):
    """The centre of pressure is a ratio (scale-free) and the spread's bound follows the spread, not the
    pad's largest taxel; an all-zero pad is exact. The graph stays inside the bound on these cases."""
    from trainer.features.hand import pad_error_bounds

    X, y = _held_grasp_cases()
    err = pad_error_bounds(X[:, :6], 1, 6)
    assert np.all(err[:, 9:14] < 1e-3)  # centre of pressure features, taxel units
    std = X[:, :6].reshape(len(X), -1).std(axis=1)
    assert np.all(err[:, 3] <= 1e-4 * std + 1e-3)
    zero = pad_error_bounds(np.zeros((2, 10, T)), 2, 5)
    assert np.all(zero[:, 4:7] == 0) and np.all(zero <= 1e-5)  # FFT shares of nothing: exactly 0 in both
    model = FeatureSVC(families=("hand",), pad_sizes=PAD_SIZES, kernel="rbf", C=10.0, gamma="scale").fit(X, y)
    runner = GraphRunner(export(model, tmp_path))
    _, _, hist = runner.run(frames_of(X))
    ref = model.transform_histograms(X)
    assert np.all(np.abs(hist - ref) <= 1e-6 + SAFETY * model.feature_error_bounds(X) + 1e-6 * np.abs(ref))
    report = compare(model, runner, frames_of(X), ["held"] * len(X))
    assert report.ok and report.features == "feature vector"


@pytest.mark.parametrize("families", FAMILY_MIXES, ids="+".join)
def test_case_features_computed_once_serve_any_subsets_fit(families, cases):
    """trainer.early.Fits fits and answers many subsets of one data set from features computed once: only
    where no family learns from the cases (else None), and then the very model a fit on the cases gives."""
    X, y = cases
    model = FeatureSVC(families=families, pad_sizes=PAD_SIZES, random_state=0)
    every = model.case_features(X)
    if {"bow", "rocket"} & set(families):
        assert every is None
        with pytest.raises(ValueError, match="learn from the training cases"):
            FeatureSVC(families=families, pad_sizes=PAD_SIZES).fit(X, y, features=np.zeros((len(X), 1)))
        return
    part = np.arange(len(X)) % 3 != 0
    plain = FeatureSVC(families=families, pad_sizes=PAD_SIZES, random_state=0).fit(X[part], y[part])
    given = FeatureSVC(families=families, pad_sizes=PAD_SIZES, random_state=0).fit(X[part], y[part], features=every[part])
    np.testing.assert_array_equal(every[~part], plain.transform_histograms(X[~part]))
    np.testing.assert_array_equal(given.svm_.dual_coef_, plain.svm_.dual_coef_)
    assert given.best_params_ == plain.best_params_
    scores, labels = given.scores_and_labels(X[~part], every[~part])
    np.testing.assert_array_equal(scores, plain.decision_function(X[~part]))
    np.testing.assert_array_equal(labels, plain.predict(X[~part]))
