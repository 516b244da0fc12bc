"""The real_slip diagnosis (studies.slip_diagnosis): its training-part checks on a small task whose
answer is known, and its report."""

from __future__ import annotations

import numpy as np

from benchmarks.studies.slip_diagnosis import VARIANTS, chunk_map, leave_one_chunk_out, markdown, search_variants
from trainer.evaluation import Split
from trainer.features.signals import pad_shapes_for
from trainer.real_tasks import RealTask


def _task() -> RealTask:
    """Two classes told apart by level; class a has three chunks, class b two; the last of each is test."""
    rng = np.random.default_rng(0)
    X, y, chunks = [], [], []
    for label, level, n_chunks in (("a", 300.0, 3), ("b", 2000.0, 2)):
        for c in range(n_chunks):
            for _ in range(6):
                X.append(level + rng.normal(0, 20, (12, 15)))
                y.append(label)
                chunks.append(f"{label}#{c}")
    X, y, chunks = np.clip(np.asarray(X), 0, 4095), np.asarray(y), np.asarray(chunks, dtype=object)
    test = np.flatnonzero(np.isin(chunks, ["a#2", "b#1"]))
    train = np.setdiff1d(np.arange(len(y)), test)
    return RealTask("toy", "toy", X, y, chunks, chunks, (12,), pad_shapes_for([12]),
                    [Split("temporal", train, test)], "last chunk of each class is test")


def test_chunk_map_and_leave_one_chunk_out():
    from trainer.defaults import default_classifier

    task = _task()
    rows = {r["chunk"]: r for r in chunk_map(task)}
    assert rows["a#2"]["part"] == "test" and rows["a#0"]["part"] == "train" and rows["b#0"]["windows"] == 6
    assert 6 < rows["a#0"]["median_peak_pct"] < 10 and rows["b#0"]["median_peak_pct"] > 45
    out = leave_one_chunk_out(task, lambda: default_classifier(task.pad_sizes, task.pad_shapes),
                              np.asarray(task.splits[0].train))
    # b keeps a single training chunk: it cannot be held out; a's two chunks are, and are recognised
    # (the default's `distinct` weighting, fitted on 12 toy windows, merges features that coincide
    # there by chance: one window of 12 goes wrong; unweighted, all 12 are right)
    assert set(out) == {"a#0", "a#1"} and np.mean([r["accuracy"] for r in out.values()]) >= 11 / 12


def test_search_variants_and_report():
    task = _task()
    task.splits = [Split("all", np.arange(len(task.y)), np.arange(0))]
    variants = search_variants([task])
    assert set(variants) == set(VARIANTS)
    assert all(0.0 <= v["mean"] <= 1.0 for v in variants.values())
    res = {"split": task.split_rule, "chunks": chunk_map(task), "contact_runs": {"toy": [30, 12]},
           "inner_grouped": {"hand+stats rbf": 0.5}, "grid": {"cells": 18, "cells_at_best": 18, "best": 0.5, "worst": 0.5},
           "leave_one_chunk_out": {"default": {"a#0": {"accuracy": 1.0, "predicted": {"a": 6}}}},
           "variants": variants, "seconds": 1.0}
    text = "\n".join(markdown(res))
    assert "| a#2 | a | train |" in text and "18 of 18 cells tie" in text and "## Findings" in text
