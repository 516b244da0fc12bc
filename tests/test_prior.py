"""The product's prior in a lab's training (trainer/prior.py): the weight is chosen by leave one lab
subject out with the prior always in the training part and never scored; ``--no-prior`` is the lab's
data alone; the evidence stream gives the early rule dormant cases; the console says onset to report
in frames and milliseconds. Synthetic throughout."""

from __future__ import annotations

import json
from typing import ClassVar

import numpy as np
import pytest
from sklearn.base import BaseEstimator, ClassifierMixin

from trainer import prior as P
from trainer.dormant import DORMANT

TINY = P.PriorRecipe(subjects=1, runs=1, idle_minutes=2.0, evidence_minutes=2.0)


class Centroid(ClassifierMixin, BaseEstimator):
    """Nearest class mean of the second channel's mean (the first carries each case's id); records what it was trained and asked on."""

    seen: ClassVar[list] = []

    def fit(self, X, y):
        self.classes_ = np.unique(y)
        f = X[:, 1].mean(axis=1)
        self.means_ = np.array([f[y == c].mean() for c in self.classes_])
        Centroid.seen.append(("fit", X[:, 0, 0].copy()))
        return self

    def predict(self, X):
        Centroid.seen.append(("predict", X[:, 0, 0].copy()))
        f = X[:, 1].mean(axis=1)
        return self.classes_[np.abs(f[:, None] - self.means_[None]).argmin(axis=1)]


def _lab(rng, n_subjects=3, per=8, noise=0.6):
    """Lab cases: class 'a' around 0, 'b' around 1, noisy; the first value of each case marks it lab (> -50)."""
    y = np.array(["a", "b"] * (n_subjects * per // 2))
    X = (y == "b").astype(float)[:, None, None] + noise * rng.standard_normal((len(y), 2, 5))
    X[:, 0, 0] = np.arange(len(y))  # a lab case's id
    groups = np.repeat([f"s{k}" for k in range(n_subjects)], per)
    return X, y, groups


def _prior(rng, n=60, flip=False):
    y = np.array(["a", "b"] * (n // 2))
    X = (y == ("a" if flip else "b")).astype(float)[:, None, None] + 0.05 * rng.standard_normal((n, 2, 5))
    X[:, 0, 0] = -100.0 - np.arange(n)  # a prior case: far below any lab id
    return P.PriorCases(X.astype(np.float32), y, np.full(n, "protocol"), P.PriorRecipe(weights=(0.0, 1.0, 2.0)))


def _ds(X, y, groups):
    from types import SimpleNamespace

    return SimpleNamespace(X=X, y=y, groups=groups)


def test_the_prior_is_always_trained_on_and_never_scored():
    rng = np.random.default_rng(0)
    X, y, groups = _lab(rng)
    prior = _prior(rng)
    Centroid.seen = []
    choice = P.choose_weight(Centroid(), _ds(X, y, groups), prior, say=lambda _: None, n_jobs=1)
    asked = np.concatenate([v for k, v in Centroid.seen if k == "predict"])
    assert (asked >= 0).all() and sorted(asked.tolist()) == sorted(list(range(len(y))) * 3), \
        "only lab cases are scored, each once per weight"
    fits = [v for k, v in Centroid.seen if k == "fit"]
    assert len(fits) == 3 * 3, "three weights x three held-out lab subjects"
    for w, fitted in zip([0, 0, 0, 1, 1, 1, 2, 2, 2], fits, strict=True):
        lab_ids = fitted[fitted >= 0]
        assert len(lab_ids) == 16, "the other two subjects' cases"
        assert np.sum(fitted < -50) == min(60, w * 16), "prior cases in every training part, by the weight"
    assert [r["n_scored"] for r in choice.rows] == [len(y)] * 3


def test_the_rule_takes_a_prior_that_helps_and_leaves_one_that_misleads():
    rng = np.random.default_rng(1)
    X, y, groups = _lab(rng, noise=1.5)
    good = P.choose_weight(Centroid(), _ds(X, y, groups), _prior(rng), say=lambda _: None)
    assert good.weight > 0 and good.rows[-1]["accuracy"] > good.rows[0]["accuracy"]
    bad = P.choose_weight(Centroid(), _ds(X, y, groups), _prior(rng, flip=True), say=lambda _: None)
    assert bad.weight == 0.0, "a prior whose labels contradict the lab's data is not used"


def test_weight_zero_is_the_lab_data_alone_and_fit_returns_the_plain_model():
    rng = np.random.default_rng(2)
    X, y, _ = _lab(rng)
    model = P.WithPrior(Centroid(), _prior(rng), 0.0).fit(X, y)
    alone = Centroid().fit(X, y)
    assert type(model) is Centroid and np.array_equal(model.means_, alone.means_)
    with_prior = P.WithPrior(Centroid(), _prior(rng), 1.0).fit(X[:, :, :3], y)  # an early head's first frames
    assert type(with_prior) is Centroid and not np.array_equal(with_prior.means_, alone.means_)


def test_the_prior_keeps_to_the_classes_the_lab_trains():
    rng = np.random.default_rng(3)
    prior = _prior(rng)
    prior.y[:10] = DORMANT
    at = prior.sample(5.0, 10, {"a", "b"})
    assert DORMANT not in set(prior.y[at].tolist()) and len(at) == 50


def test_choice_lines_put_own_and_prior_side_by_side():
    rng = np.random.default_rng(4)
    X, y, groups = _lab(rng)
    choice = P.choose_weight(Centroid(), _ds(X, y, groups), _prior(rng), say=lambda _: None)
    report = {**choice.to_dict(), "lab_cases": len(y), "evidence_windows": 0}
    lines = P.choice_lines(report)
    assert any("lab's data alone" in s for s in lines) and any("prior x2 + lab" in s for s in lines)
    assert sum("<- chosen" in s for s in lines) == 1
    md = "\n".join(P.markdown_lines(report, synthetic=True))
    assert "| the lab's data alone" in md and "**synthetic**" in md and "ties go to the larger weight" in md
    assert P.choice_lines({"off": "another sensor"}) == ["the product's prior: not used (another sensor)"]


def test_console_prints_onset_to_report_in_frames_and_ms():
    from trainer.own_replay import replay_lines

    r = {"folds": [{}], "reference": ["onset"], "events": 10, "right": 9, "wrong": 1, "missed": 0,
         "right_fraction": 0.9, "early_reports": 0, "period": 0.03125, "early_heads": "3 of 3 folds",
         "onset_to_report_frames": {"median": 6.0, "p90": 12.0}, "idle_hours": 0}
    line = replay_lines(r)[0]
    assert "median 6 frames (188 ms), p90 12 frames (375 ms)" in line and "early heads: 3 of 3 folds" in line


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """Three scripted subjects (one pose, one object, 4 actions x 2 runs) with three minutes of idle each."""
    from tests.conftest import scripted_subjects

    return scripted_subjects(tmp_path_factory, tmp_path_factory.mktemp("prior") / "data", {"s1": 0, "s2": 1, "s3": 2})


def _train(data, out, monkeypatch, *extra):
    from runtime.cli import main as handover

    monkeypatch.setattr(P, "PRIOR", TINY)
    code = handover(["train", "--data", str(data), "--out", str(out), "--no-sweep", "--repeats", "2", "--quiet",
                     "--no-real-idle", *extra])
    assert code == 0
    return json.loads((out / "metrics.json").read_text())


def test_no_prior_trains_on_the_lab_data_alone(recorded, tmp_path, monkeypatch):
    def refuse(*_a, **_k):
        raise AssertionError("--no-prior must not build the prior")

    monkeypatch.setattr(P, "use_prior", refuse)
    metrics = _train(recorded, tmp_path / "r", monkeypatch, "--no-prior", "--early", "off", "--no-replay")
    assert metrics["prior"] is None and "--no-prior" in metrics["command"]
    assert "The product's prior" not in (tmp_path / "r" / "report.md").read_text()


def test_prior_and_evidence_join_training_and_the_replay_scores_early_reports(recorded, tmp_path, monkeypatch, capsys):
    capsys.readouterr()
    metrics = _train(recorded, tmp_path / "r", monkeypatch)
    console = capsys.readouterr().out  # --quiet drops progress, not the result: the headline keeps these lines
    assert "the product's prior (" in console and "<- chosen" in console, console
    assert "early decisions: report at confidence" in console and "held-out replay through the daemon" in console
    p = metrics["prior"]
    assert [r["weight"] for r in p["candidates"]] == list(TINY.weights)
    assert p["prior_cases"]["protocol"] > 0 and any(k.startswith("idle:") for k in p["prior_cases"])
    assert p["evidence_windows"] > 0, "the early rule's dormant evidence from the prior's idle"
    assert all(r["n_scored"] == p["lab_cases"] for r in p["candidates"]), "lab cases only are scored"
    assert metrics["early"]["n_cases"] == p["lab_cases"] + p["evidence_windows"], \
        "the early rule is chosen on the lab's cases plus the prior's idle"
    assert metrics["own_replay"]["early_heads"] == "3 of 3 folds"
    assert "## The product's prior" in (tmp_path / "r" / "report.md").read_text()


def test_dormant_cut_cuts_the_lab_s_idle_and_the_prior_s_alike(recorded, tmp_path, monkeypatch):
    metrics = _train(recorded, tmp_path / "r", monkeypatch, "--dormant-cut", "in_view", "--early", "off", "--no-replay")
    assert metrics["idle"]["cut"] == "in_view" and "--dormant-cut in_view" in metrics["command"]
    kinds = {k for k in metrics["prior"]["prior_cases"] if k.startswith("idle:")}
    assert len(kinds) > 1, kinds  # every idle kind in view, not only where the trigger fired (arm moves)


def test_console_says_the_early_rule_and_where_it_reported():
    from trainer.early_report import console_line

    ev = {"rule": {"threshold": 0.95, "classes": ["pull", "push"]}, "full_accuracy": 0.98,
          "operating_point": {"reported_at": {"4": 50, "15": 20}, "accuracy": 0.97}}
    line = console_line(ev)
    assert "0.95 (pull, push early, the others wait for T)" in line and "answered 50 at frame 4, 20 at the full window (15)" in line
    assert console_line(None) is None and "not fitted (why)" in console_line({"skipped": "why"})


def test_another_sensor_trains_alone_and_says_so():
    from types import SimpleNamespace

    from firmware_io.layout import SensorLayout

    sdh2 = SensorLayout.sdh2()
    same = SimpleNamespace(pads=(0, 1), pad_sizes=tuple(len(sdh2.columns([p])) for p in (0, 1)), layout=sdh2)
    assert P.prior_problem(same) is None
    other = SimpleNamespace(pads=(0,), pad_sizes=(12,), layout=SimpleNamespace(n_taxels=12))
    why = P.prior_problem(other)
    assert "not the simulated SDH-2" in why and "\n" not in why
    said = []
    use = P.use_prior("estimator", other, said.append)
    assert use.estimator == "estimator" and use.ds is other and use.report == {"off": why} and len(said) == 1
    assert use.wrap("head") == "head"


@pytest.mark.parametrize("weight", [0.0, 1.0])
def test_when_the_lab_data_alone_wins_no_simulated_window_joins(weight, monkeypatch):
    rng = np.random.default_rng(4)
    X, y, groups = _lab(rng)
    ds, prior = _ds(X, y, groups), _prior(rng)
    monkeypatch.setattr(P, "prior_problem", lambda _ds: None)
    monkeypatch.setattr(P, "build_prior", lambda *_a: prior)
    monkeypatch.setattr(P, "choose_weight", lambda *_a: P.PriorChoice(weight, [], prior))
    with_evidence = _ds(X[:5], y[:5], groups[:5])
    monkeypatch.setattr(P, "evidence", lambda *_a: with_evidence)
    use = P.use_prior(Centroid(), ds, lambda _: None)
    if weight == 0:  # the candidate chosen is the model trained: the lab's cases, no evidence windows, no prior
        assert use.ds is ds and type(use.estimator) is Centroid and use.wrap("head") == "head"
        assert use.report["evidence_windows"] == 0 and "alone" in " ".join(P.markdown_lines(use.report, True))
    else:
        assert use.ds is with_evidence and isinstance(use.estimator, P.WithPrior)


def test_the_prior_idle_is_cut_once_per_cut_and_shared_read_only():
    """Every train of one process (the suite, the own_prior bench) with the same T, pads and trigger reads
    the same cut of the prior's idle instead of running the trigger over its frames again."""
    from types import SimpleNamespace

    from firmware_io.layout import SensorLayout
    from runtime.trigger_settings import resolve_trigger

    sdh2 = SensorLayout.sdh2()
    pads = (0, 1)

    def ds(T: int):
        return SimpleNamespace(T=T, pads=pads, trigger=resolve_trigger(), fullscale=4095.0,
                               pad_sizes=tuple(len(sdh2.columns([p])) for p in pads))

    X, origin = P._dormant_windows(TINY, "evidence", ds(15), "trigger")
    again = P._dormant_windows(TINY, "evidence", ds(15), "trigger")
    assert again[0] is X and again[1] is origin and X.shape[1:] == (sum(ds(15).pad_sizes), 15) and len(X)
    with pytest.raises(ValueError, match="read-only"):
        X[0, 0, 0] = 1.0
    shorter = P._dormant_windows(TINY, "evidence", ds(10), "trigger")[0]
    assert shorter is not X and shorter.shape[2] == 10
    every_kind = P._dormant_windows(TINY, "evidence", ds(15), "in_view")[1]
    assert len({o.split(":")[-1] for o in every_kind.tolist()}) > len({o.split(":")[-1] for o in origin.tolist()})
