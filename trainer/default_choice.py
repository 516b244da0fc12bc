"""How the shipped default is chosen, never on a test fold: nested grouped cross-validation.

Each candidate of ``trainer.select.CANDIDATES`` is scored, for every real task and outer split of the
compare, by grouped 3-fold cross-validation inside the outer training part only; its real score is
the mean over tasks. The simulated protocol is a gate, scored the same way (leave one more subject
out). The rule:

1. only candidates whose exported graph answers one case with p99 <= ``LATENCY_BUDGET_US``;
2. rank by real score (3 decimals); the best and every candidate that *ties* with it (the
   one-standard-error rule on paired per-task differences, ``ties``: a gap within the inner split's
   noise is no reason to ship a slower graph) come first, fastest median first;
3. the first in that order whose simulated inner score is >= ``SIM_GATE`` is the default (fewer than
   3 simulated subjects cannot be nested and do not gate).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["LATENCY_BUDGET_US", "apply_rule", "choose_default", "rank_with_ties", "score_order", "ties"]

SIM_GATE = 0.95
LATENCY_BUDGET_US = 1000.0
INNER_FOLDS = 3


def candidate_estimator(name: str, pad_sizes, pad_shapes, seed: int = 0, candidates=None):
    """The unfitted estimator of candidate ``name`` of ``candidates`` (default: ``trainer.select.CANDIDATES``)."""
    from trainer.defaults import DEFAULT_MODEL, paper_classifier
    from trainer.feature_svc import FeatureSVC
    from trainer.select import CANDIDATES

    _, families, kernel, settings = next(c for c in (candidates or CANDIDATES) if c[0] == name)
    if families == ("bow",):
        return paper_classifier(tuple(pad_sizes), seed, n_words=DEFAULT_MODEL["K"], window=DEFAULT_MODEL["W"],
                                kernel=kernel, per_pad=True, **settings)
    return FeatureSVC(families=families, pad_sizes=tuple(pad_sizes), pad_shapes=pad_shapes, kernel=kernel,
                      n_words=DEFAULT_MODEL["K"], window=DEFAULT_MODEL["W"], random_state=seed, **settings)


def _inner_accuracy(est, X, y, splits, n_jobs: int) -> float:
    from trainer.evaluation import run_splits

    results = run_splits(est, X, y, splits, n_jobs=n_jobs)
    return float(np.mean([np.mean(y[r["test"]] == r["y_pred"]) for r in results]))


def inner_real_score(name: str, task, n_jobs: int, seed: int = 0, candidates=None) -> float:
    """Mean over the task's outer splits of the grouped inner-CV accuracy on the outer training part
    (``candidates``: where ``name`` is defined, default ``trainer.select.CANDIDATES``)."""
    from sklearn.model_selection import StratifiedGroupKFold

    from trainer.evaluation import Split

    scores = []
    for outer in task.splits:
        tr = np.asarray(outer.train)
        X, y, groups = task.X[tr], task.y[tr], task.chunks[tr]
        n_folds = min(INNER_FOLDS, len(set(groups.tolist())))
        cv = StratifiedGroupKFold(n_splits=n_folds, shuffle=True, random_state=seed)
        inner = [Split(f"inner {i}", a, b) for i, (a, b) in enumerate(cv.split(X, y, groups))]
        est = candidate_estimator(name, task.pad_sizes, task.pad_shapes, seed, candidates)
        scores.append(_inner_accuracy(est, X, y, inner, n_jobs))
    return float(np.mean(scores))


def inner_sim_score(name: str, ds, n_jobs: int, seed: int = 0, candidates=None) -> float:
    """Nested leave-one-subject-out on the simulated protocol (synthetic): mean inner accuracy."""
    from trainer.evaluation import Split

    shapes = [(ds.layout.matrices[p].cells_y, ds.layout.matrices[p].cells_x) for p in ds.pads]
    subjects = sorted(set(ds.groups.tolist()))
    if len(subjects) < 3:
        return float("nan")  # nested leave-one-subject-out needs two subjects inside each training part
    scores = []
    for held_out in subjects:
        tr = np.flatnonzero(ds.groups != held_out)
        X, y, groups = ds.X[tr], ds.y[tr], ds.groups[tr]
        inner = [Split(s, np.flatnonzero(groups != s), np.flatnonzero(groups == s)) for s in sorted(set(groups))]
        scores.append(_inner_accuracy(candidate_estimator(name, ds.pad_sizes, shapes, seed, candidates), X, y, inner,
                                      n_jobs))
    return float(np.mean(scores))


def choose_default(tasks, ds, latency: dict, n_jobs: int, say: Callable[[str], None], seed: int = 0) -> dict:
    """Apply the rule; ``latency``: {candidate name: {"p50_us", "p99_us"}} of the exported graphs."""
    from trainer.select import CANDIDATES

    rows = {}
    for name in [c[0] for c in CANDIDATES if c[0] in latency]:
        per_task = {t.name: inner_real_score(name, t, n_jobs, seed) for t in tasks}
        rows[name] = {"real_inner": per_task, "real_score": float(np.mean(list(per_task.values()))) if per_task else 0.0,
                      **latency[name]}
        say(f"  default choice {name}: real inner score {rows[name]['real_score']:.3f} "
            + " ".join(f"{k}={v:.3f}" for k, v in per_task.items()))
    chosen, order = apply_rule(rows, lambda name: inner_sim_score(name, ds, n_jobs, seed), say)
    return {"chosen": chosen, "order": order, "rows": rows, "rule": rule_text()}


def apply_rule(rows: dict, sim_score: Callable[[str], float], say: Callable[[str], None] = lambda t: None
               ) -> tuple[str | None, list[str]]:
    """The rule on scored rows ({name: {"real_score", "real_inner", "p50_us", "p99_us"}}); ``sim_score``
    is asked lazily, in rank order, and its answer stored as ``sim_inner``."""
    eligible = [n for n in rows if (rows[n]["p99_us"] or np.inf) <= LATENCY_BUDGET_US]
    order, tied = rank_with_ties(eligible, lambda n: rows[n]["real_score"], lambda n: rows[n]["p50_us"],
                                 lambda n: rows[n]["real_inner"])
    for name in eligible:
        rows[name]["ties_best"] = name in tied
    for name in order:
        rows[name]["sim_inner"] = sim_score(name)
        say(f"  default choice {name}: simulated inner LOSO {rows[name]['sim_inner']:.3f} (synthetic)")
        if rows[name]["sim_inner"] >= SIM_GATE or np.isnan(rows[name]["sim_inner"]):
            return name, order
    return None, order


def rank_with_ties(candidates: list, score: Callable, p50_us: Callable, inner: Callable) -> tuple[list, list]:
    """``candidates`` in the rule's order: the best (``score_order``) and every one that ``ties`` it
    (``inner``: its {task or fold: accuracy}), fastest first, then the rest by ``score_order``; and the ties."""
    by_score = sorted(candidates, key=lambda c: score_order(score(c), p50_us(c)))
    tied = [c for c in by_score if ties(inner(c), inner(by_score[0]))]
    tied.sort(key=lambda c: float(p50_us(c) or 0.0))
    return tied + [c for c in by_score if not any(c is t for t in tied)], tied


def score_order(score: float, p50_us: float | None) -> tuple[float, float]:
    """Sort key of "best first": the higher score at 3 decimals, then the faster median."""
    return -round(float(score), 3), float(p50_us or 0.0)


def ties(scores: dict[str, float], best: dict[str, float]) -> bool:
    """Whether a candidate scoring ``scores`` ({task or fold: accuracy}) is as good as the best
    (``best``, same keys) by the one-standard-error rule (Hastie, Tibshirani, Friedman, *Elements of
    Statistical Learning*, 7.10) on paired differences: its mean is below the best's (both at 3
    decimals) by at most one standard error of the paired differences (equal means only, where
    there are fewer than two pairs). ``handover train --select`` uses it over folds, the default's
    rule over tasks."""
    keys = [k for k in best if k in scores]
    gap = round(float(np.mean([best[k] for k in keys])), 3) - round(float(np.mean([scores[k] for k in keys])), 3)
    if gap <= 0:
        return True
    if len(keys) < 2:
        return False
    diff = np.array([scores[k] - best[k] for k in keys])
    return bool(gap <= diff.std(ddof=1) / np.sqrt(len(diff)))


def rule_text() -> str:
    return (f"candidates of `handover train --select`; only those whose exported graph answers one case with p99 "
            f"<= {LATENCY_BUDGET_US:.0f} us; scored by the mean over real tasks of grouped {INNER_FOLDS}-fold "
            "cross-validated accuracy inside each outer training part (contact chunks as groups; the outer test "
            "folds never enter), 3 decimals; the best and every candidate that ties with it by the "
            "one-standard-error rule on paired per-task differences (its mean is below the best's by at most one "
            "standard error of the per-task differences) come first, the fastest (CPU p50) first, then the rest "
            "by score; the first in that order whose nested leave-one-subject-out accuracy on the simulated "
            f"protocol (synthetic, inside each outer training part) is >= {100 * SIM_GATE:.0f} % is the default")
