"""handover train / sweep: a small run on a tiny synthetic data set, the report folder, clear errors."""

from __future__ import annotations

import importlib.util
import json

import pytest
from protocol_standin import write_standin

from runtime.cli import main as handover


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory):
    folder = tmp_path_factory.mktemp("tiny")
    write_standin(folder, n_subjects=3, runs=3, silent=1)
    return folder


def test_train_writes_the_report_and_json(tiny_data, tmp_path, capsys):
    out = tmp_path / "report"
    sweep = {"description": "given", "mode": "config1", "seeds": [0],
             "rows": [{"param": p, p: v, "kernel": "rbf", "accuracy": 0.5, "std": 0.1}
                      for p in ("K", "W", "T") for v in (3, 9)]}
    out.mkdir()
    (out / "sweep.json").write_text(json.dumps(sweep))
    rc = handover(["train", "--data", str(tiny_data), "--out", str(out), "--pads", "distal", "--K", "6", "--W", "5",
                   "--T", "12", "--repeats", "2", "--json", "--quiet"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    metrics = json.loads(captured.out)
    for key in ("config1_accuracy_mean", "config1_accuracy_std", "loso_accuracy", "loso_per_subject",
                "baseline_loso_accuracy", "K", "W", "T", "kernel", "n_trials", "n_untriggered", "seconds"):
        assert key in metrics, key
    assert metrics["n_trials"] == 36 and metrics["n_untriggered"] == 1
    assert set(metrics["loso_per_subject"]) == {"s1", "s2", "s3"}
    assert metrics["synthetic"] is True  # the stand-in marks its recordings synthetic
    for name in ("report.md", "metrics.json", "model.joblib", "confusion_config1.png", "confusion_loso.png",
                 "tsne.png", "baseline_vs_bow.png", "sweep_K.png", "sweep_W.png", "sweep_T.png"):
        assert (out / name).is_file(), name
        if name.endswith(".png"):
            assert (out / name).stat().st_size < 150_000
    text = (out / "report.md").read_text()
    assert text.splitlines()[5].startswith("handover train --data")
    assert "synthetic" in text and "untriggered: 1" in text
    if importlib.util.find_spec("trainer.onnx_export") is not None:
        assert (out / "model.onnx").is_file() or "export failed" in str(metrics.get("onnx"))


def test_trained_model_is_deterministic_for_a_seed(tiny_data, tmp_path):
    import joblib
    import numpy as np

    models = []
    for name in ("a", "b"):
        out = tmp_path / name
        assert handover(["train", "--data", str(tiny_data), "--out", str(out), "--pads", "distal", "--K", "5",
                         "--W", "4", "--T", "10", "--repeats", "2", "--no-sweep", "--no-onnx", "--quiet"]) == 0
        models.append(joblib.load(out / "model.joblib"))
    np.testing.assert_array_equal(models[0].bow_.codebook_, models[1].bow_.codebook_)
    a, b = (json.loads((tmp_path / n / "metrics.json").read_text()) for n in ("a", "b"))
    assert a["config1"]["accuracies"] == b["config1"]["accuracies"]
    assert a["fingerprint"] == b["fingerprint"]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--data", "/nonexistent/folder"], "no such folder"),
        (["--pads", "finger-9"], "finger-9"),
        (["--W", "20", "--T", "15"], "needs T >= 21"),
    ],
)
def test_bad_input_is_one_clear_line(tiny_data, tmp_path, capsys, argv, message):
    if "--data" not in argv:
        argv = ["--data", str(tiny_data), *argv]
    rc = handover(["train", "--out", str(tmp_path / "r"), "--quiet", *argv])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.startswith("handover train: ") and message in err and "\n" not in err


def test_empty_folder_is_refused(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert handover(["train", "--data", str(tmp_path / "empty"), "--out", str(tmp_path / "r"), "--quiet"]) == 2
    assert "no .hrec recordings" in capsys.readouterr().err


def test_sweep_command_writes_results_train_can_use(tiny_data, tmp_path, capsys):
    out = tmp_path / "sw"
    rc = handover(["sweep", "--data", str(tiny_data), "--out", str(out), "--pads", "distal", "--K-values", "3,6",
                   "--W-values", "4", "--T-values", "10", "--K", "6", "--W", "4", "--T", "10", "--kernels", "linear",
                   "--repeats", "1", "--quiet", "--json"])
    assert rc == 0, capsys.readouterr().err
    result = json.loads((out / "sweep.json").read_text())
    assert [r["param"] for r in result["rows"]] == ["K", "K", "W", "T"]
    assert result["synthetic"] is True and (out / "sweep_K.png").is_file()


@pytest.mark.slow
def test_full_simulated_protocol(tmp_path, capsys):
    """The paper's 900-trial protocol from the simulator, evaluation included (a few minutes)."""
    pytest.importorskip("firmware_io.simulate")
    rc = handover(["train", "--out", str(tmp_path / "full"), "--json", "--quiet"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    metrics = json.loads(captured.out)
    assert metrics["n_trials"] == 900 and metrics["synthetic"] is True
