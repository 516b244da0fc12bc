"""README "From a real hand to a running service" after the first subject: ``handover train --data``
on one subject's recordings trains and exports the model, measures configuration 1 (pooled 80/20)
and says once, on stderr, in metrics.json and in report.md, that leave-one-subject-out needs a second
subject (synthetic stand-in data)."""

from __future__ import annotations

import json

from protocol_standin import write_standin

from runtime.cli import main as handover
from trainer.evaluation import LOSO_NEEDS_A_SECOND_SUBJECT


def test_one_subject_trains_exports_and_says_loso_needs_a_second(tmp_path, capsys):
    from runtime.model import load_model

    data, out = tmp_path / "data", tmp_path / "report"
    write_standin(data, n_subjects=1, runs=4)
    code = handover(["train", "--data", str(data), "--out", str(out), "--pads", "distal", "--K", "6", "--W", "5",
                     "--T", "12", "--repeats", "2", "--fraction", "0.15", "--no-sweep"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    notes = [line for line in captured.err.splitlines() if LOSO_NEEDS_A_SECOND_SUBJECT in line]
    assert notes == [f"handover train: {LOSO_NEEDS_A_SECOND_SUBJECT}"], captured.err
    assert "leave one subject out: not measured (leave-one-subject-out needs a second subject" in captured.out
    assert "the product's prior: not used: one lab subject" in captured.err + captured.out  # no weight to choose

    model = load_model(out / "model.onnx")
    assert model.meta.evaluation["loso_unavailable"] == LOSO_NEEDS_A_SECOND_SUBJECT

    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["loso_unavailable"] == LOSO_NEEDS_A_SECOND_SUBJECT
    for key in ("loso_accuracy", "loso_per_subject", "loso_subject_std", "baseline_loso_accuracy",
                "baseline_loso_subject_std", "config2", "baseline_config2"):
        assert metrics[key] is None, key
    assert 0.0 <= metrics["config1_accuracy_mean"] <= 1.0 and metrics["n_cases"] == 16

    text = (out / "report.md").read_text()
    assert f"not measured: {LOSO_NEEDS_A_SECOND_SUBJECT}" in text
    assert "Per class, configuration 1" in text and "Per class, configuration 2" not in text
    assert (out / "model_vs_baseline.png").is_file() and (out / "confusion_config1.png").is_file()
    assert not (out / "confusion_loso.png").exists()


def test_one_subject_select_uses_folds_grouped_by_run(tmp_path, capsys):
    """--select cannot leave a subject out either: it chooses on folds grouped by recording run."""
    data, out = tmp_path / "data", tmp_path / "report"
    write_standin(data, n_subjects=1, runs=4)
    code = handover(["train", "--data", str(data), "--out", str(out), "--pads", "distal", "--T", "12",
                     "--repeats", "2", "--fraction", "0.15", "--no-sweep", "--no-onnx", "--select", "--quiet"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert captured.err.strip() == f"handover train: {LOSO_NEEDS_A_SECOND_SUBJECT}"
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["selection"]["split"] == "one subject: folds grouped by recording run"
    assert metrics["loso_accuracy"] is None and metrics["loso_unavailable"] == LOSO_NEEDS_A_SECOND_SUBJECT
    assert "## Model selection (--select)" in (out / "report.md").read_text()
