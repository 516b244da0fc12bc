"""README "From a real hand to a running service", step 3, with one subject's session unfinished
(``handover record --max-trials 1``: one class only). Leave-one-subject-out cannot train the fold
that holds out the complete subject (its training part is one class): that fold is skipped with
one line naming the subjects and what to record, the other fold is measured, and the model is
trained and exported (synthetic scripted subjects)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from runtime.cli import main as handover
from trainer.evaluation import config2, loso_skipped, loso_splits, loso_unavailable


def _record(data, subject: str, seed: int, trials: int) -> None:
    code = handover(["record", "--device", f"subject://?seed={seed}&speed=max", "--subject", subject,
                     "--out", str(data), "--runs", "1", "--auto", "--retries", "0", "--gap", "0",
                     "--quiet", "--no-look", "--max-trials", str(trials)])
    assert code == 0


def test_unfinished_subject_skips_its_fold_and_exports(tmp_path, capsys):
    from runtime.model import load_model

    data, out = tmp_path / "data", tmp_path / "report"
    _record(data, "s1", 0, 16)
    _record(data, "s3", 1, 1)
    capsys.readouterr()
    code = handover(["train", "--data", str(data), "--out", str(out), "--pads", "distal", "--repeats", "2",
                     "--no-sweep", "--quiet"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    skips = [line for line in captured.err.splitlines() if "leaving out s1" in line]
    assert len(skips) == 1 and skips[0].startswith("handover train: "), captured.err
    assert "s3 alone" in skips[0] and "record bump, hold, push for s3" in skips[0]
    metrics = json.loads((out / "metrics.json").read_text())
    assert list(metrics["loso_per_subject"]) == ["s3"] and list(metrics["loso_skipped"]) == ["s1"]
    assert load_model(out / "model.onnx").meta.evaluation["loso_skipped"].keys() == {"s1"}
    assert "| s1 | not measured: leaving out s1" in (out / "report.md").read_text()


def test_no_fold_can_train_is_a_reason_not_a_crash():
    groups = np.array(["a"] * 4 + ["b"] * 4)
    y = np.array(["pull"] * 4 + ["push"] * 4)
    assert set(loso_skipped(groups, y)) == {"a", "b"}
    assert loso_unavailable(groups, y).startswith("no leave-one-subject-out fold can train: leaving out a")
    with pytest.raises(ValueError, match="no leave-one-subject-out fold can train"):
        loso_splits(groups, y)


def test_held_out_subject_with_one_class_is_still_a_test_fold():
    from sklearn.dummy import DummyClassifier

    groups = np.array(["a"] * 8 + ["b"] * 8 + ["c"] * 2)
    y = np.array(["pull", "push"] * 8 + ["pull", "pull"])
    X = np.zeros((len(y), 3))
    res = config2(DummyClassifier(strategy="most_frequent"), X, y, groups, n_jobs=1)
    assert set(res["per_subject"]) == {"a", "b", "c"} and res["skipped"] == {}
