"""The paper's two evaluation configurations, per-class figures, parameter sweeps and t-SNE.

Configuration 1: all subjects pooled, a random stratified 80/20 split, repeated over seeds
(mean +/- std of the test accuracy). Configuration 2: leave one subject out (train on the
others, test on that one), per subject and overall. Folds run in parallel with joblib
(at most 2 workers, one BLAS/OpenMP thread each: the machine has 2 cores).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from joblib import Parallel, delayed
from sklearn.base import clone
from sklearn.metrics import confusion_matrix, precision_recall_fscore_support
from sklearn.model_selection import train_test_split
from threadpoolctl import threadpool_limits

__all__ = [
    "LOSO_NEEDS_A_SECOND_SUBJECT", "POOLED_TEST_SIZE", "Split", "config1", "config2", "loso_skipped", "loso_splits",
    "loso_unavailable", "per_class", "pooled_splits", "run_splits", "sweep", "tsne_embedding"
]

N_JOBS = 2


@dataclass(frozen=True)
class Split:
    """One train/test split; ``name`` says what it is (seed or held-out subject)."""

    name: str
    train: np.ndarray
    test: np.ndarray


POOLED_TEST_SIZE = 0.2
"""Configuration 1's test share (the paper's 80/20)."""


def pooled_splits(y: np.ndarray, seeds: Iterable[int], test_size: float = POOLED_TEST_SIZE) -> list[Split]:
    """Configuration 1: a stratified random 80/20 split of all cases for each seed."""
    idx = np.arange(len(y))
    out = []
    for seed in seeds:
        train, test = train_test_split(idx, test_size=test_size, stratify=y, random_state=seed)
        out.append(Split(f"seed {seed}", np.sort(train), np.sort(test)))
    return out


LOSO_NEEDS_A_SECOND_SUBJECT = ("leave-one-subject-out needs a second subject: record one to measure how the model "
                               "generalises to new people")
"""Why configuration 2 is not measured on one subject's recordings (said on stderr, in metrics.json
and in report.md; the model is still trained and exported)."""


def loso_skipped(groups: np.ndarray, y: np.ndarray) -> dict[str, str]:
    """Held-out subject -> why its fold cannot run: the other subjects' cases (the fold's training
    part) hold fewer than two classes, so no classifier can be fitted. A held-out subject with few
    classes is still a valid test set; only a training part of one class is skipped."""
    groups, y = np.asarray(groups), np.asarray(y)
    labels = sorted(set(y.tolist()))
    out = {}
    for subject in sorted(set(groups.tolist())):
        others = groups != subject
        have = sorted(set(y[others].tolist()))
        if len(have) >= 2:
            continue
        who = sorted(set(groups[others].tolist()))
        lack = [c for c in labels if c not in have]
        out[str(subject)] = (f"leaving out {subject} would train on {', '.join(map(str, who))} alone, whose cases "
                             f"are all {have[0] if have else 'missing'}: record {', '.join(map(str, lack))} for "
                             f"{', '.join(map(str, who))} (handover record continues an unfinished session)")
    return out


def loso_unavailable(groups: np.ndarray, y: np.ndarray | None = None) -> str | None:
    """None when leave-one-subject-out can run at least one fold, else the reason it cannot."""
    if len(set(np.asarray(groups).tolist())) < 2:
        return LOSO_NEEDS_A_SECOND_SUBJECT
    if y is None:
        return None
    skipped = loso_skipped(groups, y)
    if len(skipped) == len(set(np.asarray(groups).tolist())):
        return "no leave-one-subject-out fold can train: " + "; ".join(skipped.values())
    return None


def loso_splits(groups: np.ndarray, y: np.ndarray | None = None) -> list[Split]:
    """Configuration 2: one split per subject, that subject's cases form the test set; given ``y``,
    the folds :func:`loso_skipped` names are left out (the caller says so)."""
    groups = np.asarray(groups)
    skip = loso_skipped(groups, y) if y is not None else {}
    out = []
    for subject in sorted(set(groups.tolist())):
        test = np.flatnonzero(groups == subject)
        train = np.flatnonzero(groups != subject)
        if set(groups[train].tolist()) & set(groups[test].tolist()):
            raise AssertionError(f"subject {subject} is in both train and test")
        if str(subject) not in skip:
            out.append(Split(str(subject), train, test))
    if len(set(groups.tolist())) < 2:
        raise ValueError(LOSO_NEEDS_A_SECOND_SUBJECT)
    if not out:
        raise ValueError(loso_unavailable(groups, y))
    return out


def _fit_predict(estimator, X: np.ndarray, y: np.ndarray, split: Split) -> dict:
    with threadpool_limits(1):
        model = clone(estimator).fit(X[split.train], y[split.train])
        pred = model.predict(X[split.test])
    return {"name": split.name, "test": split.test, "y_pred": pred}


def run_splits(estimator, X: np.ndarray, y: np.ndarray, splits: Sequence[Split], n_jobs: int = N_JOBS,
               progress: Callable[[Iterable], Iterable] | None = None) -> list[dict]:
    """Fit a clone per split (in parallel) and return its test predictions."""
    tasks = (delayed(_fit_predict)(estimator, X, y, s) for s in splits)
    results = Parallel(n_jobs=min(n_jobs, N_JOBS), return_as="generator")(tasks)
    if progress is not None:
        results = progress(results)
    return list(results)


def per_class(y_true: np.ndarray, y_pred: np.ndarray, labels: Sequence[str]) -> dict:
    """Precision, recall and support of each class."""
    p, r, _, s = precision_recall_fscore_support(y_true, y_pred, labels=list(labels), zero_division=0)
    return {c: {"precision": float(p[i]), "recall": float(r[i]), "support": int(s[i])} for i, c in enumerate(labels)}


def _summary(results: list[dict], y: np.ndarray, labels: Sequence[str]) -> dict:
    accs = {r["name"]: float(np.mean(y[r["test"]] == r["y_pred"])) for r in results}
    y_true = np.concatenate([y[r["test"]] for r in results])
    y_pred = np.concatenate([r["y_pred"] for r in results])
    return {
        "accuracies": accs,
        "confusion": confusion_matrix(y_true, y_pred, labels=list(labels)).tolist(),
        "labels": list(labels),
        "per_class": per_class(y_true, y_pred, labels),
        "pooled_accuracy": float(np.mean(y_true == y_pred)),
    }


def config1(estimator, X, y, seeds: Sequence[int] = (0, 1, 2, 3, 4), test_size: float = POOLED_TEST_SIZE,
            n_jobs: int = N_JOBS, progress=None) -> dict:
    """Pooled random stratified 80/20 splits over seeds: mean +/- std, summed confusion matrix."""
    y = np.asarray(y)
    labels = sorted(set(y.tolist()))
    splits = pooled_splits(y, seeds, test_size)
    out = _summary(run_splits(estimator, X, y, splits, n_jobs, progress), y, labels)
    accs = np.array(list(out["accuracies"].values()))
    out.update(
        mean=float(accs.mean()),
        std=float(accs.std(ddof=1)) if len(accs) > 1 else 0.0,
        split=f"stratified random {round((1 - test_size) * 100)}/{round(test_size * 100)} of all cases, "
        f"seeds {list(seeds)}; confusion summed over seeds",
    )
    return out


def config2(estimator, X, y, groups, n_jobs: int = N_JOBS, progress=None) -> dict:
    """Leave one subject out: accuracy per held-out subject and over all held-out predictions."""
    y = np.asarray(y)
    labels = sorted(set(y.tolist()))
    splits = loso_splits(groups, y)
    out = _summary(run_splits(estimator, X, y, splits, n_jobs, progress), y, labels)
    per_subject = out.pop("accuracies")
    out.update(
        per_subject=per_subject,
        skipped=loso_skipped(groups, y),
        accuracy=out["pooled_accuracy"],
        subject_mean=float(np.mean(list(per_subject.values()))),
        subject_std=float(np.std(list(per_subject.values()), ddof=1)) if len(per_subject) > 1 else 0.0,
        split="leave one subject out: train on the other subjects, test on the held-out one; "
        "overall = all held-out predictions pooled",
    )
    return out


def _sweep_task(make_estimator, params: dict, X, y, groups, mode: str, seeds: Sequence[int]) -> dict:
    est = make_estimator(params)
    with threadpool_limits(1):
        if mode == "loso":
            res = config2(est, X, y, groups, n_jobs=1)
            return {**params, "accuracy": res["accuracy"], "std": res["subject_std"], "mode": mode}
        res = config1(est, X, y, seeds=seeds, n_jobs=1)
        return {**params, "accuracy": res["mean"], "std": res["std"], "mode": mode}


def sweep(make_estimator: Callable[[dict], object], points: Sequence[tuple[dict, tuple]], mode: str = "config1",
          seeds: Sequence[int] = (0,), n_jobs: int = N_JOBS, progress=None) -> list[dict]:
    """Accuracy at each parameter point; ``points`` = [(params, (X, y, groups)), ...] (X may differ with T).

    Points run in parallel (joblib, <= 2 workers); each result is the params plus accuracy/std.
    """
    tasks = (delayed(_sweep_task)(make_estimator, p, *data, mode, tuple(seeds)) for p, data in points)
    results = Parallel(n_jobs=min(n_jobs, N_JOBS), return_as="generator")(tasks)
    if progress is not None:
        results = progress(results)
    return list(results)


def tsne_embedding(features: np.ndarray, seed: int = 0) -> np.ndarray:
    """2-D t-SNE of the histograms (the paper's separability picture). One thread: the same embedding as
    with two, and each of its 1000 gradient steps is a parallel region, so a second thread waiting for a
    busy core at every step made a few dozen cases take 20 s (0.3 s alone)."""
    from sklearn.manifold import TSNE

    features = np.asarray(features, dtype=np.float64)
    if len(features) < 2 or not np.ptp(features, axis=0).any():
        # no spread at all: sklearn divides by it and crashes the process (SIGSEGV); all cases are one point
        return np.zeros((len(features), 2))
    perplexity = float(min(30, max(2, (len(features) - 1) // 3)))
    with threadpool_limits(1):
        return TSNE(n_components=2, perplexity=perplexity, init="pca", random_state=seed).fit_transform(features)
