"""handover compare: the window rule on real recordings, the Pareto/recommendation rule, and the
CLI in --quick mode on the simulated protocol (synthetic)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from runtime.cli import main as handover
from tests.conftest import real_data_dir
from trainer.compare import CONTACT_FRACTION, FULLSCALE, ModelSpec, T, cut_windows, pareto_front, recommend


def test_pareto_front_and_recommendation():
    assert sorted(pareto_front({"a": (0.9, 100.0), "b": (0.8, 50.0), "c": (0.7, 80.0)})) == ["a", "b"]
    specs = [ModelSpec("paper", "bow", {}, "p"), ModelSpec("rich", "bow", {}, "r", "--per-pad"),
             ModelSpec("slow", "flat", {}, "f"), ModelSpec("mr", "minirocket", {}, "m")]
    sim = {"paper": {"loso_accuracy": 0.80}, "rich": {"loso_accuracy": 0.85}, "slow": {"loso_accuracy": 0.95},
           "mr": {"loso_accuracy": 0.99}}
    lat = {"paper": {"p50_us": 100.0, "p99_us": 200.0}, "rich": {"p50_us": 150.0, "p99_us": 300.0},
           "slow": {"p50_us": 5000.0, "p99_us": 9000.0}, "mr": {"p50_us": 10.0, "p99_us": 20.0}}
    rec = recommend(specs, sim, lat)
    # MiniRocket has no ONNX graph; "slow" is on the front but misses the latency budget
    assert rec["model"] == "rich" and rec["flags"] == "--per-pad" and "mr" not in rec["pareto_front"]


def test_real_windows_stay_inside_contact_chunks():
    from firmware_io.importers import import_any

    path = real_data_dir() / "kiechle" / "pressure_profiles" / "classification_video" / "pen_thin.dsa"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    rec = import_any(path)
    X, chunks = cut_windows(rec, (1, 3, 5), "pen_thin")
    assert X.shape[1:] == (sum(rec.layout.pad_sizes([1, 3, 5])), T) and len(X) == len(chunks) > 10
    # every frame of every window is in contact
    assert np.all(X.max(axis=1) >= CONTACT_FRACTION * FULLSCALE)
    assert len(set(chunks.tolist())) >= 3


@pytest.mark.slow  # about 25 s alone, a minute on the shared machine
def test_compare_cli_quick(tmp_path, capsys):
    out = tmp_path / "res"
    assert handover(["compare", "--quick", "--no-real", "--no-minirocket", "--quiet", "--json", "--out", str(out)]) == 0
    res = json.loads(capsys.readouterr().out)
    assert {p.name for p in out.iterdir()} >= {"compare.json", "compare.md", "compare.png"}
    names = [m["name"] for m in res["models"]]
    assert names[0] == "paper" and "baseline" in names and "flat-svm" in names
    for n in names:
        assert 0.0 <= res["simulated"][n]["loso_accuracy"] <= 1.0 and res["latency"][n]["p50_us"] > 0
    assert res["recommendation"]["model"] in names and res["synthetic_simulated"] is True
    md = (out / "compare.md").read_text()
    assert "synthetic" in md and "Reproduce: `handover compare --quick" in md and "Recommended default" in md
    assert "real recordings not evaluated" in md
    assert res["load_before"] and res["load_after"] and "at the start [" in md


def test_compare_cli_bad_options(capsys):
    assert handover(["compare", "--n-jobs", "5"]) == 2
    assert capsys.readouterr().err.startswith("handover compare: --n-jobs")
    assert handover(["compare", "--data", "/nonexistent/folder", "--no-minirocket"]) == 2
    assert "no such folder" in capsys.readouterr().err


def test_recommendation_says_when_a_faster_model_is_within_the_subject_spread():
    from pathlib import Path

    from trainer.compare import close_alternatives, markdown

    path = Path(__file__).resolve().parents[1] / "results" / "compare.json"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    res = json.loads(path.read_text())
    lines = close_alternatives(res)
    assert len(lines) == 1 and lines[0].startswith("**per-pad** is within the subject spread of multiscale-K16")
    assert "a quarter of the latency" in lines[0] and "synthetic" in lines[0]
    assert lines[0] in markdown(res)
    # a faster model outside the spread is not mentioned
    res["simulated"]["per-pad"]["loso_accuracy"] = 0.80
    assert close_alternatives(res) == []
