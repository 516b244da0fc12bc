"""``handover train --select``: choose the feature family and its settings on the user's own data.

Grouped cross-validation on the training data only (leave one subject out, else folds by run, else
stratified). Each candidate is exported and timed one case at a time (thread CPU time, so a shared
machine's load does not decide); those over the latency budget are out. The best mean fold accuracy
wins, and among candidates within one standard error of it (``trainer.default_choice.ties``) the
fastest. A user's held-out data is never passed in.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from trainer.train_options import TrainOptions, build_estimator

__all__ = [
    "CANDIDATES", "LATENCY_BUDGET_US", "ROCKET_SETTINGS", "Row", "markdown_lines", "rank",
    "select_model"
]

LATENCY_BUDGET_US = 1000.0
"""Default budget: single-case p99 of the exported graph (a small share of the nominal frame period,
``trainer.measure.DEADLINE_US``)."""
TIMING_REPEATS = 300
ROCKET_SETTINGS = {"C": 1.0}
"""The random-convolution family as MiniRocket uses it: thousands of PPV features and a linear head
with a fixed regularisation (an RBF kernel or a C search over that many features costs minutes per
fit on this machine and the graph misses the latency budget)."""

CANDIDATES: tuple[tuple[str, tuple[str, ...], str, dict], ...] = (
    ("stats+bow rbf", ("stats", "bow"), "rbf", {}),
    ("stats rbf", ("stats",), "rbf", {}),
    ("hand+stats rbf", ("hand", "stats"), "rbf", {}),
    ("hand+stats rbf distinct", ("hand", "stats"), "rbf", {"feature_weighting": "distinct"}),
    ("rocket+stats linear", ("rocket", "stats"), "linear", ROCKET_SETTINGS),
    ("hand rbf", ("hand",), "rbf", {}),
    ("hand+stats linear distinct", ("hand", "stats"), "linear", {"feature_weighting": "distinct"}),
    ("rocket+hand+stats linear", ("rocket", "hand", "stats"), "linear", ROCKET_SETTINGS),
    ("bow per-pad linear", ("bow",), "linear", {}),
)
"""(name, families, kernel, fixed settings); BoW with K and W from the command line."""


@dataclass
class Row:
    name: str
    families: tuple[str, ...]
    kernel: str
    settings: dict
    fold_accuracies: dict
    mean: float
    spread: float
    p50_us: float | None = None
    p99_us: float | None = None
    within_budget: bool = False
    ties_best: bool = False


@dataclass
class Selection:
    rule: str
    split: str
    budget_us: float
    rows: list[Row]
    winner: str
    estimator: object = field(repr=False, default=None)

    def to_dict(self) -> dict:
        return {"rule": self.rule, "split": self.split, "budget_us": self.budget_us, "winner": self.winner,
                "rows": [{**r.__dict__, "families": list(r.families),
                          "settings": {k: list(v) if isinstance(v, tuple) else v for k, v in r.settings.items()}}
                         for r in self.rows]}


def grouped_splits(ds) -> tuple[list, str]:
    """Leave one subject out, else grouped by run, else stratified 5-fold over trials."""
    from sklearn.model_selection import GroupKFold, StratifiedKFold

    from trainer.evaluation import Split, loso_splits, loso_unavailable

    if loso_unavailable(ds.groups, ds.y) is None:  # folds whose training part has one class are left out
        return loso_splits(ds.groups, ds.y), "leave one subject out"
    runs = np.asarray([f"{g}/{r}" for g, r in zip(ds.groups, ds.runs, strict=True)])
    if len(set(runs.tolist())) >= 2:
        cv = GroupKFold(n_splits=min(5, len(set(runs.tolist()))))
        return [Split(f"fold {i}", tr, te) for i, (tr, te) in enumerate(cv.split(ds.X, ds.y, runs))], \
            "one subject: folds grouped by recording run"
    _, counts = np.unique(ds.y, return_counts=True)
    cv = StratifiedKFold(n_splits=max(2, min(5, int(counts.min()))), shuffle=True, random_state=0)
    return [Split(f"fold {i}", tr, te) for i, (tr, te) in enumerate(cv.split(ds.X, ds.y))], \
        "one subject, one run: stratified folds over trials (each case is one trial)"


def _estimator(options: TrainOptions, ds, families: tuple[str, ...], kernel: str, settings: dict):
    est = build_estimator(replace(options, features=families, kernel=kernel, per_pad=True), ds)
    return est.set_params(**settings)


def graph_latency(model, ds, folder: Path, name: str, seed: int) -> dict:
    """Single-case p50/p99 (us) of the exported graph through the runtime's loader (1 thread)."""
    from runtime.model import load_model
    from trainer.measure import cycling, export_metadata, percentiles, time_calls
    from trainer.onnx_export import export_onnx

    path = export_onnx(model, folder / f"{name.replace(' ', '_')}.onnx", export_metadata(ds, model, seed=seed))
    loaded = load_model(path)
    rng = np.random.default_rng(seed)
    cases = [np.ascontiguousarray(ds.X[i : i + 1].transpose(0, 2, 1), dtype=np.float32)
             for i in rng.integers(0, len(ds.X), 32)]
    return percentiles(time_calls(cycling(loaded.run, cases), TIMING_REPEATS, cpu=True))


def select_model(ds, options: TrainOptions, say: Callable[[str], None] = lambda text: None,
                 candidates=CANDIDATES) -> Selection:
    """Evaluate every candidate by grouped CV and latency; return the selection with the winner's
    unfitted estimator."""
    from threadpoolctl import threadpool_limits

    from trainer.evaluation import run_splits

    budget = float(options.latency_budget_us or LATENCY_BUDGET_US)
    splits, split_rule = grouped_splits(ds)
    rows = []
    with tempfile.TemporaryDirectory(prefix="handover-select-") as tmp:
        for name, families, kernel, settings in candidates:
            est = _estimator(options, ds, families, kernel, settings)
            results = run_splits(est, ds.X, ds.y, splits, n_jobs=2)
            accs = {r["name"]: float(np.mean(ds.y[r["test"]] == r["y_pred"])) for r in results}
            values = np.asarray(list(accs.values()))
            row = Row(name, families, kernel, settings, accs, float(values.mean()),
                      float(values.std(ddof=1)) if len(values) > 1 else 0.0)
            with threadpool_limits(1):
                stats = graph_latency(est.fit(ds.X, ds.y), ds, Path(tmp), name, int(options.seed))
            row.p50_us, row.p99_us = stats["p50"], stats["p99"]
            row.within_budget = row.p99_us <= budget
            rows.append(row)
            say(f"  select {name}: {100 * row.mean:.1f} % +/- {100 * row.spread:.1f} ({split_rule}), "
                f"p99 {row.p99_us:.0f} us{'' if row.within_budget else ' (over the budget)'}")
    winner = rank(rows)
    rule = (f"highest mean accuracy over the folds ({split_rule}, training data only), 3 decimals, among "
            f"candidates whose exported graph answers one case with p99 <= {budget:.0f} us; a candidate within one "
            "standard error of the best (paired per-fold differences, the same rule as the shipped default's) "
            "ties with it, and of the ties the fastest wins")
    return Selection(rule, split_rule, budget, rows, winner.name,
                     _estimator(options, ds, winner.families, winner.kernel, winner.settings))


def rank(rows: list[Row]) -> Row:
    """Sort ``rows`` in the rule's order (within the budget first; the best and its ties, fastest
    first; then by score) and return the winner (``trainer.default_choice.ties``)."""
    from trainer.default_choice import rank_with_ties, score_order

    eligible = [r for r in rows if r.within_budget] or list(rows)
    order, tied = rank_with_ties(eligible, lambda r: r.mean, lambda r: r.p50_us, lambda r: r.fold_accuracies)
    for r in rows:
        r.ties_best = any(r is t for t in tied)
    rest = sorted((r for r in rows if not any(r is e for e in eligible)), key=lambda r: score_order(r.mean, r.p50_us))
    rows[:] = order + rest
    return rows[0]


def markdown_lines(selection: Selection) -> list[str]:
    """The selection table for the training report."""
    lines = ["", "## Model selection (--select)", "", f"Rule: {selection.rule}.", "",
             "| candidate | families | kernel | mean accuracy | spread (std over folds) | ties the best | p50 us | "
             "p99 us | within budget |", "|---|---|---|---|---|---|---|---|---|"]
    for r in selection.rows:
        star = " **(winner)**" if r.name == selection.winner else ""
        lines.append(f"| {r.name}{star} | {', '.join(r.families)} | {r.kernel} | {100 * r.mean:.1f} % | "
                     f"{100 * r.spread:.1f} | {'yes' if r.ties_best else 'no'} | {r.p50_us:.0f} | {r.p99_us:.0f} | "
                     f"{'yes' if r.within_budget else 'no'} |")
    return lines
