"""./dev bench compare: the window rule on real recordings, the Pareto/recommendation rule, and the
CLI in --quick mode on the simulated protocol (synthetic)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from benchmarks.__main__ import main as bench
from benchmarks.compare import CONTACT_FRACTION, FULLSCALE, T, cut_windows, pareto_front
from tests.conftest import real_data_dir


def test_pareto_front():
    assert sorted(pareto_front({"a": (0.9, 100.0), "b": (0.8, 50.0), "c": (0.7, 80.0)})) == ["a", "b"]


def test_default_rule_ranks_by_real_inner_score_gates_on_simulation_and_latency():
    from trainer.default_choice import apply_rule

    rows = {"fast": {"real_score": 0.70, "p50_us": 50.0, "p99_us": 90.0},
            "best": {"real_score": 0.80, "p50_us": 200.0, "p99_us": 400.0},
            "slow": {"real_score": 0.95, "p50_us": 900.0, "p99_us": 5000.0},
            "tie": {"real_score": 0.8001, "p50_us": 100.0, "p99_us": 300.0}}
    for row in rows.values():
        row["real_inner"] = {"a": row["real_score"], "b": row["real_score"]}  # no spread: only equal scores tie
    sims = {"tie": 0.90, "best": 0.97, "fast": 0.99}
    asked = []

    def sim(name):
        asked.append(name)
        return sims[name]

    chosen, order = apply_rule(rows, sim)
    # "slow" misses the latency budget; "tie" equals "best" at 3 decimals and is faster, so it is
    # asked first, but fails the simulated gate; "fast" is never asked
    assert order == ["tie", "best", "fast"] and chosen == "best" and asked == ["tie", "best"]
    assert "sim_inner" not in rows["fast"]


def test_a_gap_within_one_standard_error_of_paired_task_differences_is_a_tie():
    from trainer.default_choice import apply_rule, ties

    best = {"real_inner": {"a": 0.70, "b": 0.60, "c": 0.80}, "real_score": 0.70, "p50_us": 200.0, "p99_us": 400.0}
    noisy = {"real_inner": {"a": 0.74, "b": 0.50, "c": 0.84}, "real_score": 0.6933, "p50_us": 80.0, "p99_us": 150.0}
    steady = {"real_inner": {"a": 0.69, "b": 0.59, "c": 0.79}, "real_score": 0.69, "p50_us": 60.0, "p99_us": 100.0}
    # noisy: gap 0.7 points, differences +4/-10/+4 (standard error 4.7 points): a tie
    # steady: gap 1 point every task alike (standard error 0): worse, not a tie
    assert ties(noisy["real_inner"], best["real_inner"]) and not ties(steady["real_inner"], best["real_inner"])
    rows = {"best": best, "noisy": noisy, "steady": steady}
    chosen, order = apply_rule(rows, lambda name: 0.99)
    assert order == ["noisy", "best", "steady"] and chosen == "noisy"
    assert rows["noisy"]["ties_best"] and rows["best"]["ties_best"] and not rows["steady"]["ties_best"]
    assert not ties({"a": 0.69}, {"a": 0.70}) and ties({"a": 0.70}, {"a": 0.70})


def test_real_windows_stay_inside_contact_chunks():
    from firmware_io.recordings.importers import import_any

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
    assert bench(["compare", "--quick", "--no-real", "--no-minirocket", "--quiet", "--json", "--out", str(out)]) == 0
    res = json.loads(capsys.readouterr().out)
    assert {p.name for p in out.iterdir()} >= {"compare.json", "compare.md", "compare.png"}
    names = [m["name"] for m in res["models"]]
    assert names[0] == "default" and {"paper", "baseline", "flat-svm", "stats"} <= set(names)
    for n in names:
        assert 0.0 <= res["simulated"][n]["loso_accuracy"] <= 1.0 and res["latency"][n]["p50_us"] > 0
    # no real tasks: the rule has nothing to rank by but keeps the latency budget and names a candidate
    assert res["recommendation"]["chosen"] in {"stats rbf", "hand rbf"} and res["synthetic_simulated"] is True
    assert all(res["latency"][n]["cpu_p99_us"] > 0 for n in names)
    md = (out / "compare.md").read_text()
    assert "synthetic" in md and "Reproduce: `./dev bench compare --quick" in md and "## Choosing the default" in md
    assert "real recordings not evaluated" in md
    assert res["load_before"] and res["load_after"] and "at the start [" in md


def test_compare_cli_bad_options(capsys):
    assert bench(["compare", "--n-jobs", "5"]) == 2
    assert capsys.readouterr().err.startswith("./dev bench compare: --n-jobs")
    assert bench(["compare", "--data", "/nonexistent/folder", "--no-minirocket"]) == 2
    assert "no such folder" in capsys.readouterr().err


def test_done_check_reads_the_spread_of_the_best_reference():
    from benchmarks.compare import done_check

    def entry(acc, folds):
        return {"accuracy": acc, "per_split": {f"f{i}": v for i, v in enumerate(folds)}}

    res = {"real": {"a": {"results": {"default": entry(0.70, [0.7, 0.7]), "baseline": entry(0.75, [0.65, 0.85]),
                                      "flat-svm": entry(0.5, [0.5, 0.5])}},
                    "b": {"results": {"default": entry(0.9, [0.9]), "minirocket": entry(0.8, [0.8])}},
                    "c": {"results": {"default": entry(0.5, [0.5]), "minirocket": entry(0.8, [0.8])}}}}
    lines = done_check(res)
    assert "within its fold spread" in lines[0] and "at or above" in lines[1] and "outside the spread" in lines[2]


def test_compare_an_unusable_out_folder_is_one_line_before_the_run(tmp_path, capsys, monkeypatch):
    """--out naming a file raised FileExistsError with a traceback, and only after the whole run (a
    real compare takes an hour): the folder is checked first, its error is one line."""
    from benchmarks import compare

    def run(*_a, **_k):
        raise AssertionError("ran before checking --out")

    monkeypatch.setattr(compare, "run", run)
    (tmp_path / "file").write_text("")
    for out in (tmp_path / "file", tmp_path / "file" / "below"):
        assert bench(["compare", "--quick", "--no-real", "--no-minirocket", "--quiet", "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"./dev bench compare: --out {out}: {tmp_path / 'file'} is a file") and err.count("\n") == 1, err
