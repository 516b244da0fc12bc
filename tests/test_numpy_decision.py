"""The latency benchmark's numpy-only yardstick decides like the graph it is read from."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from tests.onnx_fixtures import export, fit_model, frames_of, metadata, synthetic_cases
from trainer.bench.numpy_bow import NumpyBow
from trainer.bench.numpy_decision import numpy_decision
from trainer.bench.numpy_features import NumpyFeatures
from trainer.defaults import DEFAULT_MODEL
from trainer.feature_svc import FeatureSVC
from trainer.onnx_export import export_onnx
from trainer.stress import stress_cases
from trainer.verify import GraphRunner

T = 15


def _windows(pad_sizes: tuple[int, ...], n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``(n, C, T)`` cases from empty to fully pressed pads (both sides of the zero-median shortcut)."""
    rng = np.random.default_rng(seed)
    C = sum(pad_sizes)
    y = np.arange(n) % 4
    X = np.zeros((n, C, T))
    for i in range(n):
        share = (0.02, 0.3, 0.7, 1.0)[(i // 4) % 4]
        active = rng.random(C) < share
        base = rng.integers(0, 3000, C)[:, None]
        slope = (y[i] - 1.5) * 100.0 * np.arange(T)[None] * rng.random((C, 1))
        X[i] = np.clip(base + slope + rng.normal(0.0, 25.0, (C, T)), 0, 4095).round() * active[:, None]
    return X, np.array(["pull", "push", "hold", "bump"])[y]


def _default_like(pad_shapes: list[tuple[int, int]], tmp_path, kernel: str = DEFAULT_MODEL["kernel"]):
    sizes = tuple(r * c for r, c in pad_shapes)
    X, y = _windows(sizes, 96, seed=1)
    model = FeatureSVC(families=DEFAULT_MODEL["families"], pad_sizes=sizes, pad_shapes=pad_shapes, kernel=kernel,
                       C=10.0, gamma="scale" if kernel == "rbf" else None).fit(X, y)
    meta = {**metadata(), "pads": list(range(len(sizes))), "pad_sizes": list(sizes)}
    return export_onnx(model, tmp_path / f"{kernel}-{len(sizes)}.onnx", meta), sizes


def _assert_same_as_graph(path, frames: np.ndarray) -> None:
    decide = numpy_decision(path)
    assert decide is not None
    labels, scores, _ = GraphRunner(path).run(frames)
    for window, label, score in zip(frames, labels, scores, strict=True):
        got_label, got_scores = decide(window)
        assert got_label == label
        assert got_scores.dtype == np.float32
        np.testing.assert_allclose(got_scores, score, rtol=1e-5, atol=2e-5)


# 14 x 6 and 13 x 6: SDH-2 proximal and distal pads (padded to one size); 13 x 6 twice: no padding
@pytest.mark.parametrize("pad_shapes", [[(14, 6), (13, 6), (14, 6)], [(13, 6), (13, 6)]], ids=["padded", "equal"])
def test_feature_default_same_label_and_scores_as_the_graph(pad_shapes, tmp_path):
    path, sizes = _default_like(pad_shapes, tmp_path)
    assert isinstance(numpy_decision(path), NumpyFeatures)
    X, _ = _windows(sizes, 160, seed=7)
    stress = stress_cases(T, sum(sizes), np.eye(2, 4) * 100.0, seed=1)
    _assert_same_as_graph(path, np.concatenate([frames_of(X), *stress.values()]))


def test_feature_default_with_a_linear_svm(tmp_path):
    path, sizes = _default_like([(14, 6), (13, 6)], tmp_path, kernel="linear")
    _assert_same_as_graph(path, frames_of(_windows(sizes, 64, seed=8)[0]))


def test_bow_default_same_label_and_scores_as_the_graph(tmp_path):
    path = export(fit_model("linear", per_pad=True), tmp_path)
    assert isinstance(numpy_decision(path), NumpyBow)
    assert numpy_decision(export(fit_model("rbf"), tmp_path, "rbf.onnx")) is None  # not implemented: no yardstick
    _assert_same_as_graph(path, frames_of(synthetic_cases(n=32, seed=5)[0]))


def test_decides_without_scikit_learn(tmp_path):
    """Loading and deciding import no scikit-learn (the yardstick is numpy only)."""
    path, sizes = _default_like([(13, 6), (13, 6)], tmp_path)
    code = ("import sys; sys.modules['sklearn'] = None\n"
            "import numpy as np\n"
            "from trainer.bench.numpy_decision import numpy_decision\n"
            f"label, scores = numpy_decision({str(path)!r})(np.ones(({T}, {sum(sizes)}), np.float32))\n"
            "print(label, scores.shape)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split()[1] == "(4,)"
