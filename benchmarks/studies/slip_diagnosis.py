"""Why the default loses on ``real_slip``, judged on that task's training part only, and whether a
different SVM search would improve the default by the rule's own measure (issue #12).

Writes ``results/slip_diagnosis.{json,md}``. Nothing here is chosen on a test part: the chunk map
lists the test chunks' windows and levels only to describe what the split asks; every comparison
of methods runs inside outer training parts (real_slip's first 60 % of each file's chunks, and the
rule's nested grouped 3-fold on every real task).

Run: ``./dev bench slip_diagnosis --out results``.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import time
import warnings
from pathlib import Path

import numpy as np

VARIANTS = {
    "shipped: stratified 3-fold search, shuffled (C x gamma 0.1/1/10 x scale)": ("shuffled", (0.1, 1.0, 10.0), "rbf"),
    "search grouped by contact chunk": ("grouped", (0.1, 1.0, 10.0), "rbf"),
    "gamma grid widened to 0.01 x scale": ("shuffled", (0.01, 0.1, 1.0, 10.0), "rbf"),
    "linear kernel, C searched": ("shuffled", (), "linear"),
    "stats block weight 0.5/1/2 chosen by grouped search": ("weighted", (0.1, 1.0, 10.0), "rbf"),
}
"""SVM searches tried for the default's features; (folds, gamma factors, kernel)."""


def former_split_task(task):
    """real_slip with the one split it had when this diagnosis was written (``first_part_split``): the
    diagnosis explains that split's verdict; the compare now uses blocked folds (``SLIP_SPLIT``)."""
    from dataclasses import replace

    from trainer.evaluation import Split
    from trainer.real_tasks import first_part_split

    train, test = first_part_split(task.y, task.chunks)
    return replace(task, splits=[Split("first 60 % of each file's chunks / rest", train, test)],
                   split_rule="temporal: first 60 % of each file's contact chunks train, the rest test "
                              "(real_slip's split until 2026-11-24)")


def chunk_map(task) -> list[dict]:
    """Every chunk: class, part of the outer split, windows, median peak taxel (% of full scale)."""
    from trainer.real_tasks import FULLSCALE

    train = set(np.asarray(task.splits[0].train).tolist())
    rows = []
    for chunk in dict.fromkeys(task.chunks.tolist()):
        idx = np.flatnonzero(task.chunks == chunk)
        peak = task.X[idx].max(axis=(1, 2)) / FULLSCALE
        rows.append({"chunk": chunk, "class": str(task.y[idx[0]]), "part": "train" if idx[0] in train else "test",
                     "windows": len(idx), "median_peak_pct": round(100 * float(np.median(peak)), 1)})
    return rows


def contact_runs(bags: Path) -> dict[str, list[int]]:
    """Frames of each contact run of each bag (the window rule's 5 % level on all pads), in order."""
    from firmware_io.importers import import_any

    from trainer.real_tasks import ALL_PADS, CONTACT_FRACTION, FULLSCALE

    out = {}
    for name in ("no_slippage", "slip_down", "slip_up"):
        rec = import_any(bags / f"{name}.bag")
        contact = rec.frames[:, rec.layout.columns(list(ALL_PADS))].max(axis=1) >= CONTACT_FRACTION * FULLSCALE
        edges = np.flatnonzero(np.diff(np.concatenate([[0], contact.astype(np.int8), [0]])))
        out[name] = [int(b - a) for a, b in zip(edges[::2], edges[1::2], strict=True)]
    return out


def leave_one_chunk_out(task, make, train_idx: np.ndarray) -> dict:
    """Inside the training part: hold out each chunk whose class keeps another training chunk."""
    X, y, ch = task.X[train_idx], task.y[train_idx], task.chunks[train_idx]
    out = {}
    for chunk in dict.fromkeys(ch.tolist()):
        test = ch == chunk
        if len(set(ch[(y == y[test][0]) & ~test].tolist())) == 0:
            continue  # the class would vanish from training
        pred = make().fit(X[~test], y[~test]).predict(X[test])
        labels, counts = np.unique(pred, return_counts=True)
        out[chunk] = {"accuracy": float(np.mean(pred == y[test])),
                      "predicted": {str(k): int(v) for k, v in zip(labels, counts, strict=True)}}
    return out


def grid_ties(task, train_idx: np.ndarray) -> dict:
    """The default's C x gamma grid scored by grouped 3-fold on the training part: how many cells tie."""
    from sklearn.model_selection import GridSearchCV, StratifiedGroupKFold
    from sklearn.svm import SVC

    from trainer.classifier import C_GRID, GAMMA_FACTORS
    from trainer.defaults import default_classifier

    X, y, ch = task.X[train_idx], task.y[train_idx], task.chunks[train_idx]
    est = default_classifier(task.pad_sizes, task.pad_shapes).set_params(C=1.0, gamma=1.0).fit(X, y)
    Z = est.scaler_.transform(est.transform_histograms(X))
    scale = 1.0 / (Z.shape[1] * Z.var())
    grid = {"C": list(C_GRID), "gamma": [scale * f for f in GAMMA_FACTORS]}
    cv = StratifiedGroupKFold(3, shuffle=True, random_state=0)
    scores = GridSearchCV(SVC(), grid, cv=cv).fit(Z, y, groups=ch).cv_results_["mean_test_score"]
    return {"cells": len(scores), "best": float(np.max(scores)), "worst": float(np.min(scores)),
            "cells_at_best": int(np.sum(scores >= np.max(scores) - 1e-12))}


def _search(Z, y, groups, folds: str, factors, kernel: str):
    from sklearn.exceptions import FitFailedWarning
    from sklearn.model_selection import GridSearchCV, StratifiedGroupKFold, StratifiedKFold
    from sklearn.svm import SVC

    from trainer.classifier import C_GRID

    grid = {"C": list(C_GRID)}
    if kernel == "rbf":
        grid["gamma"] = [f / (Z.shape[1] * Z.var()) for f in factors]
    cv = (StratifiedKFold(3, shuffle=True, random_state=0) if folds == "shuffled"
          else StratifiedGroupKFold(3, shuffle=True, random_state=0))
    with warnings.catch_warnings():  # a grouped fold without some class scores NaN for that cell, by design
        warnings.simplefilter("ignore", FitFailedWarning)
        warnings.simplefilter("ignore", UserWarning)
        return GridSearchCV(SVC(kernel=kernel), grid, cv=cv).fit(Z, y, groups=None if folds == "shuffled" else groups)


def variant_accuracy(Za, ya, ga, Zb, yb, n_first: int, spec) -> float:
    """Held-out accuracy of one search variant on standardised features (``n_first``: hand block width)."""
    folds, factors, kernel = spec
    if folds != "weighted":
        return float(np.mean(_search(Za, ya, ga, folds, factors, kernel).predict(Zb) == yb))
    best = None
    for weight in (0.5, 1.0, 2.0):
        w = np.ones(Za.shape[1])
        w[n_first:] = weight
        s = _search(Za * w, ya, ga, "grouped", factors, kernel)
        if best is None or s.best_score_ > best[0] + 1e-12:
            best = (s.best_score_, float(np.mean(s.predict(Zb * w) == yb)))
    return best[1]


def search_variants(tasks) -> dict:
    """Each variant scored by the rule's nested protocol (grouped 3-fold inside every outer training part)."""
    from sklearn.model_selection import StratifiedGroupKFold

    from trainer.defaults import default_classifier

    table = {name: {} for name in VARIANTS}
    for task in tasks:
        accs = {name: [] for name in VARIANTS}
        for outer in task.splits:
            tr = np.asarray(outer.train)
            X, y, g = task.X[tr], task.y[tr], task.chunks[tr]
            for a, b in StratifiedGroupKFold(3, shuffle=True, random_state=0).split(X, y, g):
                est = default_classifier(task.pad_sizes, task.pad_shapes).set_params(C=1.0, gamma=1.0).fit(X[a], y[a])
                Za = est.scaler_.transform(est.transform_histograms(X[a]))
                Zb = est.scaler_.transform(est.transform_histograms(X[b]))
                n_first = est.blocks_[0][1].n_features_out_
                for name, spec in VARIANTS.items():
                    accs[name].append(variant_accuracy(Za, y[a], g[a], Zb, y[b], n_first, spec))
        for name in VARIANTS:
            table[name][task.name] = float(np.mean(accs[name]))
    return {name: {"per_task": per, "mean": float(np.mean(list(per.values())))} for name, per in table.items()}


def run(data_dir: Path, say) -> dict:
    from benchmarks.compare import machine_info
    from trainer.default_choice import inner_real_score
    from trainer.defaults import default_classifier
    from trainer.feature_svc import FeatureSVC
    from trainer.flat import FlatSVC
    from trainer.real_tasks import real_tasks
    from trainer.select import CANDIDATES

    t0 = time.perf_counter()
    load_before = [round(v, 2) for v in os.getloadavg()]
    tasks, notes = real_tasks(data_dir)
    slip = next((t for t in tasks if t.name == "real_slip"), None)
    if slip is None:
        raise FileNotFoundError(f"real_slip's recordings are not under {data_dir}: {notes}")
    slip = former_split_task(slip)
    train = np.asarray(slip.splits[0].train)
    say("real_slip: inner scores, leave one chunk out, grid ...")
    makers = {"default": lambda: default_classifier(slip.pad_sizes, slip.pad_shapes),
              "stats": lambda: FeatureSVC(families=("stats",), pad_sizes=slip.pad_sizes, pad_shapes=slip.pad_shapes),
              "hand": lambda: FeatureSVC(families=("hand",), pad_sizes=slip.pad_sizes, pad_shapes=slip.pad_shapes),
              "flat-svm": FlatSVC}
    result = {
        "chunks": chunk_map(slip),
        "contact_runs": contact_runs(Path(data_dir) / "sdh2-dsa" / "mas-group" / "slip_detection" / "bag"),
        "split": slip.split_rule,
        "inner_grouped": {name: inner_real_score(name, slip, n_jobs=2) for name, *_ in CANDIDATES},
        "leave_one_chunk_out": {name: leave_one_chunk_out(slip, make, train) for name, make in makers.items()},
        "grid": grid_ties(slip, train),
    }
    say("search variants on every real task (nested, training parts only) ...")
    result["variants"] = search_variants(tasks)
    result.update(seconds=round(time.perf_counter() - t0, 1), machine=machine_info(), load_before=load_before,
                  load_after=[round(v, 2) for v in os.getloadavg()])
    return result


def markdown(res: dict) -> list[str]:
    lines = ["# real_slip: why the default loses, on the training part only", "",
             f"Split: {res['split']}. Chunks (a contact run cut at 96 frames; the test rows are listed only to say "
             "what the split asks, nothing below is scored on them):", "",
             "| chunk | class | part | windows | median peak taxel (% of full scale) |", "|---|---|---|---|---|"]
    lines += [f"| {c['chunk']} | {c['class']} | {c['part']} | {c['windows']} | {c['median_peak_pct']} |"
              for c in res["chunks"]]
    lines += ["", "Contact runs per bag (frames at or above the 5 % level, in order; chunks cut them at 96 frames, "
              "runs shorter than T = 15 give no window): "
              + "; ".join(f"{k}: {', '.join(map(str, v))}" for k, v in res["contact_runs"].items()) + "."]
    lines += ["", "Grouped 3-fold inside the training part (the rule's real_slip score), per candidate: "
              + ", ".join(f"{k} {100 * v:.1f} %" for k, v in res["inner_grouped"].items()) + ".", "",
              "Leave one chunk out inside the training part (chunks whose class keeps another training chunk):", "",
              "| model | " + " | ".join(next(iter(res["leave_one_chunk_out"].values()))) + " |",
              "|---|" + "---|" * len(next(iter(res["leave_one_chunk_out"].values())))]
    for name, per in res["leave_one_chunk_out"].items():
        lines.append(f"| {name} | " + " | ".join(f"{100 * r['accuracy']:.0f} % {r['predicted']}" for r in per.values())
                     + " |")
    g = res["grid"]
    lines += ["", f"The default's C x gamma grid scored by grouped 3-fold on the training part: {g['cells_at_best']} "
              f"of {g['cells']} cells tie at the best score {100 * g['best']:.1f} % (worst {100 * g['worst']:.1f} %).",
              "", "## SVM searches for the default's features, by the rule's measure", "",
              "Nested: grouped 3-fold inside every outer training part of every real task (as "
              "trainer/default_choice.py scores candidates); mean accuracy %.", ""]
    names = list(next(iter(res["variants"].values()))["per_task"])
    lines += ["| search | mean | " + " | ".join(names) + " |", "|---|---|" + "---|" * len(names)]
    for variant, r in res["variants"].items():
        lines.append(f"| {variant} | {100 * r['mean']:.1f} | "
                     + " | ".join(f"{100 * r['per_task'][n]:.1f}" for n in names) + " |")
    return [*lines, "", *FINDINGS, "", f"Ran in {res['seconds']:.0f} s."]


FINDINGS = [
    "## Findings",
    "",
    "- Each bag is one recording with one slip event, and every window is labelled with the bag's kind: the "
    "windows are holds before and after that event, at levels that differ by bag (table above). The outer "
    "split gives slip_down one training chunk and slip_up one (its 1-window chunk aside), so the training part "
    "holds one example grasp per slip kind.",
    "- On that training part no grouped evaluation separates the methods: the rule's grouped 3-fold scores "
    "every candidate the same (a fold that holds the only slip_down chunk has no slip_down to train on); "
    "leaving out a chunk whose class keeps another, the default, stats alone, hand alone and the flattened SVM "
    "make the same predictions; every C x gamma cell of the default's search ties. The test verdict "
    "(default 70.8 %, stats and flat-svm 100 % in results/compare.md) is decided by one test chunk "
    "(slip_up.bag#7, 9 of 24 windows) and cannot be foreseen from the training data.",
    "- Suspects: 84 hand features diluting the RBF distance, gamma 'scale' on concatenated groups: neither "
    "shows on the training part (hand alone, stats alone and both behave alike there; weighting the stats "
    "block by a grouped search does not help on the other tasks either). The pad layout is SDH-2's (6 pads, "
    "13 x 6 and 14 x 6); pads 1 and 2 read zero in all three bags (constant features, no effect after "
    "scaling). The contact-chunk rule matters: after slip_up's "
    "slip the grip hovers at the 5 % level, so contact flickers and the run breaks into short chunks.",
    "- Not a flaw of the rule: real_slip adds the same inner score to every candidate, so it does not move "
    "the ranking; the done criterion on real_slip rests on a single split whose outcome is one chunk.",
    "- SVM searches a careful engineer might ship (grouped by contact chunk, a wider gamma grid, a linear "
    "kernel, a searched block weight) all score at or below the shipped search by the rule's own nested "
    "measure (table above), so the default estimator is left as it is.",
]


def main(argv: list[str] | None = None) -> int:
    from trainer.measure import write_results
    from trainer.shared_data import default_data_dir

    parser = argparse.ArgumentParser(prog="./dev bench slip_diagnosis", description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="results")
    parser.add_argument("--data", help="shared data folder holding sdh2-dsa/ (default ../shared/data)")
    args = parser.parse_args(argv)
    try:
        res = run(Path(args.data) if args.data else default_data_dir(), lambda t: print(t, file=sys.stderr, flush=True))
    except (OSError, ValueError) as exc:
        print(f"slip_diagnosis: {exc}", file=sys.stderr)
        return 2
    res["command"] = shlex.join(["./dev", "bench", "slip_diagnosis", "--out", args.out]
                                + (["--data", args.data] if args.data else []))
    from benchmarks.studies.weighting_check import kept_section, upsert_section

    kept = kept_section(Path(args.out) / "slip_diagnosis.md")
    write_results(args.out, "slip_diagnosis", res, markdown(res))
    if kept:  # the feature-weighting check's dated section outlives a rerun of this diagnosis
        upsert_section(Path(args.out) / "slip_diagnosis.md", kept)
    return 0
