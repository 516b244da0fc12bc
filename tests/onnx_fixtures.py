"""Small fitted models and their exported graphs for the ONNX tests (synthetic data, seeded)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

PAD_SIZES = (6, 10)
T = 12
ACTION_NAMES = np.array(["pull", "push", "hold", "bump"])


def synthetic_cases(n: int = 96, seed: int = 0, n_classes: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Synthetic ``(n, C, T)`` cases: class-dependent slopes on random offsets, some series all zero."""
    rng = np.random.default_rng(seed)
    C = sum(PAD_SIZES)
    y = np.arange(n) % n_classes
    X = np.zeros((n, C, T))
    for i in range(n):
        active = rng.random(C) < 0.7
        base = rng.integers(0, 3000, C)[:, None]
        slope = (y[i] - 1.5) * 120.0 * np.arange(T)[None] * rng.random((C, 1))
        X[i] = np.clip(base + slope + rng.normal(0.0, 25.0, (C, T)), 0, 4095).round() * active[:, None]
    return X, ACTION_NAMES[y]


def fit_model(kernel: str = "rbf", per_pad: bool = True, n_classes: int = 4, C: float = 10.0, gamma=None, seed: int = 0):
    from trainer.classifier import BowSVC

    X, y = synthetic_cases(seed=seed, n_classes=n_classes)
    kw = {"gamma": "scale" if gamma is None else gamma} if kernel == "rbf" else {}
    return BowSVC(n_words=6, window=5, kernel=kernel, C=C, per_pad=per_pad, pad_sizes=PAD_SIZES, **kw).fit(X, y)


def metadata() -> dict:
    return {"pads": [1, 3], "pad_sizes": list(PAD_SIZES), "training": {"data_fingerprint": "synthetic-test", "n_trials": 96}}


def export(model, folder: Path, name: str = "model.onnx", **kw) -> Path:
    from trainer.onnx_export import export_onnx

    return export_onnx(model, Path(folder) / name, metadata(), **kw)


def frames_of(X: np.ndarray) -> np.ndarray:
    """Aeon ``(n, C, T)`` cases as graph input ``[n, T, C]`` float32."""
    return np.ascontiguousarray(np.asarray(X).transpose(0, 2, 1), dtype=np.float32)


def check_report(report) -> None:
    """A verified graph: no NaN/inf, every disagreement with the reference a true near tie."""
    from trainer.numerics import SAFETY

    assert report.nan_or_inf_outputs == 0
    assert report.unexplained_disagreements == 0, report.disagreements
    assert report.hist_mismatch_unexplained == 0
    for d in report.disagreements:
        assert d.near_tie and min(d.codeword_margin, d.svm_margin) < SAFETY
