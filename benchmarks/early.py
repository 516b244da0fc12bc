"""``./dev bench early``: how early a decision can be, against aeon's early classifiers.

Real SDH-2 recordings first (``trainer.real_tasks``: every task found in ../shared/data, its own
grouped splits; a decision after ``p`` frames reads the first ``p`` frames of a case), then the
simulated protocol (synthetic, leave one subject out). Per task and method: accuracy at 4, 8 and
15 frames (the heads alone), and the early rule's operating point: accuracy, earliness (mean
frames used / frames of a case) and their harmonic mean (2 acc (1 - earliness) / (acc + 1 -
earliness), the usual score of early classification).

``--quick``: every real task with its first split only, the protocol with one run per subject and two
held-out subjects. Methods, all on the same windows and splits:

- ``default``: ``trainer.early`` (heads of the product default at each point, the report rule
  chosen by grouped cross-validation inside the training part: chunks of the real tasks, subjects
  of the protocol; target accuracy loss ``trainer.early.TARGET_LOSS``);
- ``aeon ProbabilityThreshold`` and ``aeon TEASER``: aeon's early classifiers at the same points,
  each with aeon's ``SummaryClassifier`` (per-channel summary statistics and a random forest) as the
  classifier at every point: their own defaults (DrCIF, MUSE) take hours on hundreds of channels.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from trainer.measure import command_line, load_average, machine_info, write_results

NAME = "early"
SHOWN = (4, 8, 15)
"""The points every row reports accuracy at."""
INNER_FOLDS = 3
"""Groups (contact chunks) of a real task's training part are joined into this many folds for the rule."""
AEON_TREES = 50


def fold_ids(groups: np.ndarray, k: int) -> np.ndarray:
    """Groups joined round robin (sorted) into at most ``k`` folds: the inner cross-validation's groups."""
    names = sorted(set(np.asarray(groups).astype(str).tolist()))
    index = {g: i % k for i, g in enumerate(names)}
    return np.asarray([index[g] for g in np.asarray(groups).astype(str).tolist()])


def points_for(n_frames: int) -> tuple[int, ...]:
    """The early points of a case of ``n_frames`` (the default's, and 15 where a case is longer)."""
    from trainer.early import EARLY_POINTS

    return tuple(p for p in sorted({*EARLY_POINTS, *SHOWN}) if p < n_frames)


def ours(Xtr, ytr, gtr, Xte, yte, pad_sizes, pad_shapes, seed: int) -> dict:
    """The default's heads and rule trained on one training part, scored on its test part."""
    from trainer import early

    n = Xtr.shape[2]
    points = points_for(n)
    make = early.head_factory(pad_sizes, pad_shapes, seed)
    heads = early.fit_early(Xtr, ytr, gtr, make, make, points)
    full = make(n).fit(Xtr, ytr)
    classes = sorted({str(c) for c in ytr})
    truth = np.asarray([classes.index(str(c)) if str(c) in classes else -1 for c in yte])
    labels, margins = early.answers([*heads.models, full], (*points, n), Xte, classes)
    conf = early.confidences(margins[:-1], heads.spec.calibration)
    where, said = early.cascade(labels[:-1], conf, labels[-1], heads.spec.needs(classes), heads.spec.agree)
    frames = np.asarray([*points, n])[where]
    at = {str(p): float(np.mean(labels[k] == truth)) for k, p in enumerate((*points, n)) if p in SHOWN or p == n}
    return {"at": at, "accuracy": float(np.mean(said == truth)), "mean_frames": float(frames.mean()),
            "rule": heads.spec.to_meta(), "n_test": len(yte)}


def aeon_method(kind: str, Xtr, ytr, Xte, yte, seed: int) -> dict:
    """aeon's ProbabilityThresholdEarlyClassifier or TEASER at the default's points."""
    from aeon.classification.early_classification import TEASER, ProbabilityThresholdEarlyClassifier
    from aeon.classification.feature_based import SummaryClassifier
    from sklearn.ensemble import RandomForestClassifier

    n = Xtr.shape[2]
    points = [*points_for(n), n]
    base = SummaryClassifier(estimator=RandomForestClassifier(n_estimators=AEON_TREES, random_state=seed),
                             random_state=seed)
    cls = ProbabilityThresholdEarlyClassifier if kind == "threshold" else TEASER
    clf = cls(estimator=base, classification_points=points, random_state=seed)
    Xtr64, Xte64 = Xtr.astype(np.float64), Xte.astype(np.float64)
    clf.fit(Xtr64, np.asarray(ytr).astype(str))
    _, acc, earliness = clf.score(Xte64, np.asarray(yte).astype(str))
    at = {}
    for k, p in enumerate(clf._classification_points):
        if p in SHOWN or p == n:
            pred = clf._estimators[k].predict(Xte64[:, :, :p]) if hasattr(clf, "_estimators") else \
                clf.estimators_[k].predict(Xte64[:, :, :p])
            at[str(p)] = float(np.mean(np.asarray(pred).astype(str) == np.asarray(yte).astype(str)))
    return {"at": at, "accuracy": float(acc), "mean_frames": float(earliness) * n, "n_test": len(yte)}


METHODS = ("default", "aeon ProbabilityThreshold", "aeon TEASER")


def run_task(name: str, X, y, groups_of_split, splits, pad_sizes, pad_shapes, seed: int, say) -> dict:
    """Every method on every split of one task; pooled over the splits (weighted by test cases)."""
    rows: dict[str, list] = {m: [] for m in METHODS}
    for i, (train, test) in enumerate(splits):
        say(f"early: {name} split {i + 1}/{len(splits)} ...")
        gtr = groups_of_split(train)
        rows["default"].append(ours(X[train], y[train], gtr, X[test], y[test], pad_sizes, pad_shapes, seed))
        for method, kind in (("aeon ProbabilityThreshold", "threshold"), ("aeon TEASER", "teaser")):
            t0 = time.perf_counter()
            rows[method].append(aeon_method(kind, X[train], y[train], X[test], y[test], seed))
            rows[method][-1]["seconds"] = round(time.perf_counter() - t0, 1)
    n = X.shape[2]
    return {m: pooled(r, n) for m, r in rows.items()}


def pooled(rows: list[dict], n_frames: int) -> dict:
    from trainer.early import earliness_score

    w = np.asarray([r["n_test"] for r in rows], dtype=np.float64)
    acc = float(np.average([r["accuracy"] for r in rows], weights=w))
    frames = float(np.average([r["mean_frames"] for r in rows], weights=w))
    at = {p: float(np.average([r["at"][p] for r in rows], weights=w)) for p in rows[0]["at"]}
    out = {"at": at, "mean_frames": frames, "n_frames": n_frames, **earliness_score(acc, frames, n_frames),
           "folds": rows}
    return out


def run(args) -> dict:
    from firmware_io.sim import simulate_protocol
    from trainer.dataset import build_dataset
    from trainer.real_tasks import real_tasks
    from trainer.shared_data import default_data_dir

    say = args.say
    seed = args.seed
    t0 = time.perf_counter()
    result: dict = {"benchmark": NAME, "command": command_line(NAME, args), "machine": machine_info(), "tasks": {},
                    "load_before": load_average(),
                    "notes": []}
    data_dir = default_data_dir()
    tasks, notes = real_tasks(data_dir, seed) if data_dir.is_dir() else ([], [f"{data_dir}: absent, no real task"])
    result["notes"] += notes
    for task in tasks:
        split_list = [(s.train, s.test) for s in task.splits][: 1 if args.quick else None]
        chunks = np.asarray(task.chunks).astype(str)
        result["tasks"][task.name] = {"real": True, "description": task.description, "split_rule": task.split_rule,
                                      "n_cases": len(task.y), "methods": run_task(
                                          task.name, task.X, task.y, lambda idx, c=chunks: fold_ids(c[idx], INNER_FOLDS),
                                          split_list, task.pad_sizes, task.pad_shapes, seed, say)}
    say(f"early: the simulated protocol (synthetic, seed {seed}) ...")
    ds = build_dataset(simulate_protocol(seed=seed, runs=1 if args.quick else 5), T=15, pads="all")
    shapes = [(ds.layout.matrices[p].cells_y, ds.layout.matrices[p].cells_x) for p in ds.pads]
    subjects = np.asarray(ds.groups).astype(str)
    loso = [(np.flatnonzero(subjects != s), np.flatnonzero(subjects == s)) for s in sorted(set(subjects.tolist()))]
    result["tasks"]["simulated_protocol"] = {
        "real": False, "description": "simulated protocol (synthetic), onset-triggered windows, all pads",
        "split_rule": "leave one subject out; the rule inside each training part by leave one subject out",
        "n_cases": len(ds.y), "methods": run_task("simulated protocol", ds.X, ds.y, lambda idx: subjects[idx],
                                                  loso[:2] if args.quick else loso, ds.pad_sizes, shapes, seed, say)}
    result["verdict"] = verdict(result)
    result["seconds"] = round(time.perf_counter() - t0, 1)
    result["load_after"] = load_average()
    write_results(Path(args.out), NAME, result, markdown(result))
    hm = result["verdict"]
    result["early_default_hm_mean"] = hm["default_hm_mean"]
    return result


def verdict(result: dict) -> dict:
    """Mean harmonic mean per method over the real tasks (the claim), and whether the default's is highest."""
    real = [t for t in result["tasks"].values() if t["real"]]
    mean = {m: (float(np.mean([t["methods"][m]["harmonic_mean"] for t in real])) if real else None) for m in METHODS}
    best_other = max((v for m, v in mean.items() if m != "default" and v is not None), default=None)
    return {"real_hm_mean": mean, "default_hm_mean": mean["default"],
            "default_above_aeon": None if best_other is None or mean["default"] is None else mean["default"] > best_other}


def markdown(result: dict) -> list[str]:
    lines = ["# Early decisions against aeon's early classifiers", "",
             "Made by:", "", "```", result["command"], "```", "",
             f"Machine: {result['machine']['cpu']}, {result['machine']['cores']} cores; {result['seconds']} s.", "",
             "Per task and method: accuracy of each point's classifier alone at 4, 8 and 15 frames (the first frames "
             "of each case), then the early rule's accuracy, earliness (mean frames used / frames of a case) and "
             "their harmonic mean (HM). `default`: trainer/early.py (heads of the product default, rule chosen by "
             "grouped cross-validation inside each training part for an accuracy within 2 points of the full "
             "window's). aeon's ProbabilityThresholdEarlyClassifier (threshold 0.85) and TEASER at the same points, "
             "each with aeon's SummaryClassifier (random forest of "
             f"{AEON_TREES} trees) at every point (their defaults, DrCIF and MUSE, take hours on hundreds of "
             "channels). Same windows and splits for all.", ""]
    v = result["verdict"]
    if v["default_hm_mean"] is not None:
        means = ", ".join(f"{m} {x:.3f}" for m, x in v["real_hm_mean"].items())
        lines += [f"**Mean HM over the real tasks: {means}.** The default's is "
                  f"{'above' if v['default_above_aeon'] else 'NOT above'} both aeon rows.", ""]
    lines += ["| task | method | acc @4 | acc @8 | acc @15 | rule accuracy | mean frames | earliness | HM |",
              "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for name, task in result["tasks"].items():
        tag = name if task["real"] else f"{name} (**synthetic**)"
        for m, r in task["methods"].items():
            at = [f"{r['at'][str(p)]:.1%}" if str(p) in r["at"] else "-" for p in SHOWN]
            lines.append(f"| {tag} | {m} | {' | '.join(at)} | {r['accuracy']:.1%} | {r['mean_frames']:.1f} of "
                         f"{r['n_frames']} | {r['earliness']:.2f} | {r['harmonic_mean']:.3f} |")
    lines += ["", "Tasks and splits:", ""]
    lines += [f"- {name}: {t['description']}; {t['split_rule']}; {t['n_cases']} cases" for name, t in result["tasks"].items()]
    if result["notes"]:
        lines += ["", *[f"- {n}" for n in result["notes"]]]
    return lines
