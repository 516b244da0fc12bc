"""handover train / sweep: a small run on a tiny synthetic data set, the report folder, clear errors."""

from __future__ import annotations

import hashlib
import json
import re

import pytest
from protocol_standin import write_standin

from runtime.cli import main as handover


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory):
    folder = tmp_path_factory.mktemp("tiny")
    write_standin(folder, n_subjects=3, runs=3, silent=1)
    return folder


def test_train_writes_the_report_and_json(tiny_data, tmp_path, capsys):
    # --fraction 0.15: the stand-in (noise on every taxel) is a fixture of the paper's threshold trigger
    out = tmp_path / "report"
    sweep = {"description": "given", "mode": "config1", "seeds": [0],
             "rows": [{"param": p, p: v, "kernel": "rbf", "accuracy": 0.5, "std": 0.1}
                      for p in ("K", "W", "T") for v in (3, 9)]}
    out.mkdir()
    (out / "sweep.json").write_text(json.dumps(sweep))
    rc = handover(["train", "--data", str(tiny_data), "--out", str(out), "--pads", "distal", "--K", "6", "--W", "5",
                   "--T", "12", "--repeats", "2", "--fraction", "0.15", "--features", "bow", "--json", "--quiet",
                   "--no-prior"])  # the report's keys are the question; tests/test_prior.py covers its prior section
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
                 "tsne.png", "model_vs_baseline.png", "sweep_K.png", "sweep_W.png", "sweep_T.png"):
        assert (out / name).is_file(), name
        if name.endswith(".png"):
            assert (out / name).stat().st_size < 150_000
    text = (out / "report.md").read_text()
    assert text.splitlines()[5].startswith("handover train --data")
    assert "synthetic" in text and "labelled trials that gave no window: 1**" in text
    assert "windows that end before the annotated onset" in text and "SVM margin of the final model" in text
    assert metrics["n_windows_before_onset"] >= 0 and metrics["W"] == 5 and metrics["windows"] == [5]
    margin = metrics["svm_margin"]
    assert margin["C"] == metrics["best_params"]["C"] and 0.0 <= margin["share_at_bound"] <= 1.0
    assert ("hard margin" if margin["hard_margin"] else "soft margin") in text
    saved = json.loads((out / "metrics.json").read_text())
    assert saved["dataset"]["windows_before_onset"] == metrics["n_windows_before_onset"]
    # the ONNX file names the joblib it was exported from by sha256: verify can refuse a mix-up
    from runtime.model import load_model

    ref = load_model(out / "model.onnx").meta.extra["reference"]
    assert ref["file"] == "model.joblib"
    assert ref["sha256"] == hashlib.sha256((out / "model.joblib").read_bytes()).hexdigest()


def test_trained_model_is_deterministic_for_a_seed(tiny_data, tmp_path):
    import joblib
    import numpy as np

    models = []
    for name in ("a", "b"):
        out = tmp_path / name
        assert handover(["train", "--data", str(tiny_data), "--out", str(out), "--pads", "all", "--K", "5",
                         "--W", "4", "--T", "10", "--repeats", "2", "--no-sweep", "--no-onnx", "--fraction", "0.15", "--quiet",
                         "--no-prior", "--no-replay"]) == 0  # the model is the question (the replay reads it, after);
        # tests/test_prior.py covers the prior
        saved = joblib.load(out / "model.joblib")
        assert set(saved) == {"model", "metadata", "early"} and saved["metadata"]["pads"] == [0, 1, 2, 3, 4, 5]
        models.append(saved["model"])
    from trainer.defaults import DEFAULT_MODEL

    # without options: the product default of trainer/defaults.py
    assert tuple(models[0].families) == DEFAULT_MODEL["families"] and models[0].kernel == DEFAULT_MODEL["kernel"]
    np.testing.assert_array_equal(models[0].svm_.dual_coef_, models[1].svm_.dual_coef_)
    np.testing.assert_array_equal(models[0].scaler_.mean_, models[1].scaler_.mean_)
    a, b = (json.loads((tmp_path / n / "metrics.json").read_text()) for n in ("a", "b"))
    assert a["config1"]["accuracies"] == b["config1"]["accuracies"]
    assert a["fingerprint"] == b["fingerprint"]


def test_export_of_a_trained_file_needs_no_pads_and_keeps_the_card(tiny_data, tmp_path, capsys):
    """handover export model.joblib (no --pads) on a model of all pads: the pads and the
    provenance come from the file, not from the distal default."""
    out = tmp_path / "prox"
    assert handover(["train", "--data", str(tiny_data), "--out", str(out), "--pads", "all", "--K", "4",
                     "--W", "4", "--T", "10", "--repeats", "2", "--no-sweep", "--no-onnx", "--fraction", "0.15", "--quiet"]) == 0
    rc = handover(["export", str(out / "model.joblib"), "--out", str(out / "exported.onnx")])
    printed = capsys.readouterr()
    assert rc == 0, printed.err
    wrote = printed.out.strip().splitlines()[-1]  # the default features have no codebook: no K, no W
    assert ", T=10, features: hand + stats, per pad (6 pads)" in wrote and "K=" not in wrote, wrote
    from runtime.model import load_model

    meta = load_model(out / "exported.onnx").meta
    assert list(meta.pads) == [0, 1, 2, 3, 4, 5] and meta.n_channels == 486
    assert meta.training["n_trials"] == 36 and meta.training["data_fingerprint"] != "unknown"
    assert meta.evaluation["loso_accuracy"] is not None
    capsys.readouterr()
    assert handover(["inspect", str(out / "exported.onnx")]) == 0
    card = capsys.readouterr().out
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["n_untriggered"] > 0, "the stand-in's silent trials give no window"
    assert "None windows" not in card and (f"trained on: {metrics['n_cases']} windows from 36 labelled trials "
                                           f"({metrics['n_untriggered']} gave no window), data") in card


def test_failed_onnx_export_fails_the_command(tiny_data, tmp_path, capsys):
    out = tmp_path / "fail"
    (out / "model.onnx").mkdir(parents=True)  # the export cannot replace a directory
    rc = handover(["train", "--data", str(tiny_data), "--out", str(out), "--pads", "distal", "--K", "4",
                   "--windows", "3,5", "--T", "10", "--repeats", "2", "--no-sweep", "--fraction", "0.15", "--quiet",
                   "--no-prior", "--early", "off", "--no-replay"])  # the export's failure is the question
    err = capsys.readouterr().err
    assert rc == 1 and "model.onnx not written" in err
    metrics = json.loads((out / "metrics.json").read_text())  # the report is still written
    assert metrics["windows"] == [3, 5] and metrics["W"] == 5 and metrics["onnx"].startswith("export failed")


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--data", "/nonexistent/folder"], "no such folder"),
        (["--pads", "finger-9"], "finger-9"),
        (["--W", "20", "--T", "15", "--features", "bow"], "needs T >= 21"),
        (["--features", "bow", "--feature-weighting", "distinct"], "not to bow alone"),
        (["--out", "/dev/null/x"], "--out /dev/null/x: /dev/null is a file, not a folder"),  # before training
        # W is the BoW window: a model without BoW is not refused for it (the data error comes first)
        (["--data", "/nonexistent/folder", "--W", "20", "--T", "15", "--features", "stats"], "no such folder"),
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
    pytest.importorskip("firmware_io.sim")
    rc = handover(["train", "--out", str(tmp_path / "full"), "--json", "--quiet"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    metrics = json.loads(captured.out)
    assert metrics["n_trials"] == 900 and metrics["synthetic"] is True


def test_train_options_take_a_plain_string_of_features_and_check_the_pads():
    from trainer.train_options import OptionsError, TrainOptions

    assert TrainOptions(features="stats").families == ("stats",)
    assert TrainOptions(features="stats, bow").families == ("stats", "bow")
    TrainOptions(features="stats").check()
    with pytest.raises(OptionsError, match=r"^--features 's,t': give distinct names from"):
        TrainOptions(features="s,t").check()
    with pytest.raises(OptionsError, match=r"^--pads '9': pad selection '9': no matrix 9"):
        TrainOptions(pads="9").check()  # the simulated protocol is an SDH-2: refused before simulating it
    with pytest.raises(OptionsError, match=r"^--pads 'nine': unknown pad selection"):
        TrainOptions(pads="nine", data="somewhere").check()
    TrainOptions(pads="9", data="somewhere").check()  # recorded data: checked against its own layout once loaded
    with pytest.raises(OptionsError, match=r"^--dormant-cut 'all': use one of trigger, in_view, both"):
        TrainOptions(dormant_cut="all").check()
    with pytest.raises(OptionsError, match=r"^--dormant-cut both: it cuts the dormant class from recorded idle"):
        TrainOptions(dormant_cut="both", data="somewhere", dormant=False).check()


def test_pads_no_hand_has_is_refused_before_simulating(tmp_path, capsys):
    assert handover(["train", "--pads", "9", "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["handover train: --pads '9': pad selection '9': no matrix 9 (sensor has 6)"]  # no "simulating"


@pytest.mark.parametrize(("trigger", "cause"), [
    (["--fraction", "0.9"], "the threshold trigger needs a rising edge to 0.9 x full scale, and pulls lower the "
                            "pressure: try --trigger onset or a lower --fraction"),
    ([], "trials must start from the settled grasp: the onset trigger takes each trial's first frame as the "
         "baseline"),
])
def test_too_few_triggered_trials_say_which_classes_never_triggered_and_why(tmp_path, capsys, trigger, cause):
    from protocol_standin import write_standin

    data = tmp_path / "data"
    write_standin(data, n_subjects=1, runs=2, late=8)  # every trial acts too late to cut a window (noise may fire)
    assert handover(["train", "--data", str(data), "--out", str(tmp_path / "r"), "--quiet", "--no-sweep",
                     *trigger]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("handover train: only "), err
    assert "too few to train (at least 10 cases of 2 classes)" in err[0]
    assert re.search(r"; \d+ trials gave no case \(((bump|hold|pull|push) \d+(, )?)+\): (never triggered|triggered too late) \d+", err[0]), err[0]
    assert cause in err[0]


def test_enough_cases_to_train_but_not_to_split_say_so_in_the_trainers_words(tmp_path, capsys):
    """Five runs of each action by one subject, 12-14 of them triggered: enough to train, but the stratified
    80/20 split cannot hold four classes in 3 test cases (was the splitter's own sentence about test_size)."""
    data = tmp_path / "data"
    write_standin(data, n_subjects=1, runs=5)
    assert handover(["train", "--data", str(data), "--out", str(tmp_path / "r"), "--quiet", "--no-sweep",
                     "--early", "off", "--no-real-idle"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and re.match(r"handover train: only 1[0-5] triggered cases of 4 classes", err[0]), err
    assert "record more runs of each action (handover record --runs)" in err[0] and "test_size" not in err[0]


def test_train_without_data_names_the_recordings_record_wrote(tmp_path, monkeypatch, capsys):
    """record writes ./recordings by default; train without --data simulates: it says so, naming the folder."""
    from trainer.commands import train_cli

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(train_cli, "run", lambda options: 0)  # the line comes before any training
    assert handover(["train", "--out", "report"]) == 0
    assert "--data recordings" not in capsys.readouterr().err
    (tmp_path / "recordings").mkdir()
    (tmp_path / "recordings" / "subject_s1.hrec").write_bytes(b"")
    assert handover(["train", "--out", "report"]) == 0
    said = [line for line in capsys.readouterr().err.splitlines() if "--data recordings" in line]
    assert len(said) == 1 and "simulated protocol (synthetic)" in said[0], said
