"""Smoke tests of ``handover bench`` in --quick mode (tiny sizes): they run and write their files
and keys. No timing is asserted: speed is measured by the benchmarks, not by unit tests."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np
import pytest

from benchmarks.__main__ import main as bench
from benchmarks.pareto import grid, is_default, pareto_front
from trainer.bench.latency_stages import STAGES
from trainer.commands import bench_cli
from trainer.measure import deadline_ratio, percentiles, tap_stream


def _args(which: str, out, *extra: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    bench_cli.add_arguments(parser)
    return parser.parse_args([which, "--quick", "--quiet", "--json", "--out", str(out), *extra])


def _run(which: str, tmp_path, capsys, *extra: str) -> tuple[dict, dict]:
    """Run one benchmark as ``./dev bench`` does; the product's three also as ``handover bench``."""
    assert bench([which, "--quick", "--quiet", "--json", "--out", str(tmp_path), *extra]) == 0
    printed = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    result = json.loads((tmp_path / f"{which}.json").read_text())
    md = (tmp_path / f"{which}.md").read_text()
    runner = "handover" if which in bench_cli.BENCHMARKS else "./dev"
    assert result["command"].startswith(f"{runner} bench {which} --quick")
    assert result["command"] in md and "Machine:" in md
    for key in ("cpu", "cores", "python", "numpy", "onnxruntime", "load_average"):
        assert key in result["machine"]
    return printed, result


def test_percentiles_and_deadline_ratio():
    s = percentiles(np.arange(1, 1001, dtype=float))
    assert s["n"] == 1000 and s["p50"] == pytest.approx(500.5) and s["max"] == 1000.0
    assert s["p50"] <= s["p99"] <= s["p999"] <= s["max"]
    assert deadline_ratio(s)["max"] == pytest.approx(31.25)
    assert percentiles([])["p50"] is None


def test_pareto_front_marks_only_undominated_points():
    pts = [(10.0, 0.5), (20.0, 0.2), (30.0, 0.3), (5.0, 0.9), (20.0, 0.2)]
    assert pareto_front(pts) == [True, True, False, True, True]


def test_full_grid_holds_the_default_and_every_variant():
    points = grid(quick=False)
    assert sum(is_default(p) for p in points) == 1
    assert {p["kernel"] for p in points} == {"rbf", "linear"}
    assert {p["pads"] for p in points} == {"all", "distal"}
    assert {p["per_pad"] for p in points} == {True, False}
    assert all(p["T"] - 1 >= p["W"] for p in points)


def test_tap_stream_triggers_once_per_window():
    rec = tap_stream(quick=True, n_windows=5, gap=5)
    assert len(rec.trials) == 5 and rec.meta["synthetic"]
    cols = rec.layout.columns("all")
    level = rec.frames[:, cols].max(axis=1)
    for t in rec.trials:  # untouched before each window, so the trigger re-arms
        assert level[t.first - 1] == 0


def test_pareto_quick(tmp_path, capsys):
    printed, result = _run("pareto", tmp_path, capsys)
    assert (tmp_path / "pareto.png").stat().st_size > 0
    for key in ("onnx_p50_us", "onnx_p99_us", "default_on_front"):
        assert key in printed
    kinds = {r["kind"] for r in result["rows"]}
    assert {"bow", "baseline"} <= kinds and "sklearn" not in kinds  # one benchmark a question: bench inference
    assert sum(r["default"] for r in result["rows"]) == 1
    assert any(r["on_front"] for r in result["rows"])
    assert all(0.0 <= r["loso_error"] <= 1.0 for r in result["rows"])
    assert result["synthetic"] is True


def test_latency_quick(tmp_path, capsys):
    printed, result = _run("latency", tmp_path, capsys, "--duration", "2")
    assert (tmp_path / "latency.png").stat().st_size > 0
    for key in ("onnx_p50_us", "onnx_p50_us_all_pads", "daemon_p999_us", "e2e_p999_us", "paced_over_back_to_back",
                "rss_mb"):
        assert printed[key] > 0
    for rhythm in ("back_to_back", "paced_32hz"):
        table = result["stages"][rhythm]
        assert all(table[stage]["n"] > 0 for stage in STAGES)  # every stage of every decision stamped
        assert table["total"]["p50"] > table["inference"]["p50"] > 0
    # continuous mode: every frame a decision (frames of the ring's first window excepted), each kept warm
    continuous = result["stages"]["continuous_paced_32hz"]
    assert continuous["daemon_internal"]["n"] == continuous["inference"]["n"] > 10
    assert result["continuous_daemon_p50_us"] == continuous["daemon_internal"]["p50"] > 0
    md = (tmp_path / "latency.md").read_text()
    assert "continuous mode, paced at 32 Hz" in md
    # a stranger read "(a change of class)" and n = 1 rows: the md says which rule reports and what n counts
    assert "a change of class" not in md and "confirm_frames" in md and "continuous_daemon_p999_us" in md
    assert continuous["handle_frame_no_decision"]["n"] == result["model"]["T"] - 1 and "first T - 1 frames" in md
    imps = result["implementations"]
    # the graph alone (one benchmark a question: the graph against scikit-learn is bench inference's)
    assert set(imps["back_to_back"]) == set(imps["solo"]) == {"onnxruntime"}
    # the headline is the graph alone (warm)
    assert printed["onnx_p50_us"] == result["implementations_distal"]["solo"]["onnxruntime"]["p50"]
    assert printed["onnx_p50_us_all_pads"] == imps["solo"]["onnxruntime"]["p50"]
    assert "numpy_over_onnx_p50" not in printed and "sklearn_over_onnx_p50" not in printed
    assert "onnxruntime, distal pads" in (tmp_path / "latency.md").read_text()
    # serving with a candidate in shadow against serving alone, alternating blocks of the same process
    shadow = result["shadow"]
    assert shadow["serving"]["n"] == shadow["shadow"]["n"] > 0 and printed["shadow_p999_ratio"] > 0
    assert shadow["shadow_counts"]["shadow"]["windows_compared"] + shadow["shadow_counts"]["shadow"]["windows_dropped"] > 0
    assert "## Serving with a candidate in shadow" in md and "`shadow_p999_ratio`" in md
    # and with field capture on top: every paced decision's window captured, none dropped
    assert shadow["shadow + capture"]["n"] == shadow["serving"]["n"] and printed["shadow_capture_p999_ratio"] > 0
    assert shadow["capture_counts"]["capture_events"] > 0 and shadow["capture_counts"]["capture_dropped"] == 0
    # the limits: a steady job can only be slowed by the machine; the split's scores are the whole graph's
    assert result["floor_p999_us"] >= result["daemon_p50_us"] * 0.99 and result["e2e_floor_p999_us"] > 0
    split = result["implementations_distal"]["per_frame_split"]
    assert split["max_score_difference"] < 1e-4 and result["split_p50_us"] == split["decision_with_its_frame_p50_us"]
    assert split["nodes"]["per_frame_part"] + split["nodes"]["decision_part"] >= split["nodes"]["whole"]
    e2e = result["e2e_32hz"]
    # at most one event per window (the trigger re-arms between them), each matching a window; on a busy machine
    # the first windows may pass while the daemon still loads its model, so not every window need give one
    assert 0 < e2e["events"] <= e2e["windows_sent"] and e2e["unmatched"] == 0
    assert e2e["e2e_us"]["p50"] > e2e["daemon_internal_us"]["p50"] > 0  # the wire and the sink add time


def test_throughput_quick(tmp_path, capsys):
    printed, result = _run("throughput", tmp_path, capsys)
    assert printed["replay_frames_per_s"] > 0 and printed["rss_mb"] > 0
    assert 0.0 < result["cpu_share"] < 2.0
    assert result["startup_to_ready_s"] > 0
    assert result["replay_hot_path"]["decisions"] == 40
    assert result["replay_daemon"]["decisions"] == 40  # the daemon's own trigger fires once per window too
    assert "swap_to_log_s" in result["footprint"]  # may be None in 3 s on a busy machine


def test_bad_duration_is_one_line(tmp_path, capsys):
    from runtime.cli import main as handover

    for argv in (["bench", "latency", "--duration", "-1"], ["bench", "inference", "--repeats", "0"]):
        with pytest.raises(SystemExit) as stop:
            handover([*argv, "--out", str(tmp_path)])
        err = capsys.readouterr().err.strip().splitlines()
        assert stop.value.code == 2 and len(err) == 1 and err[0].startswith(f"handover bench: argument {argv[2]}"), err
    assert bench(["soak", "--hours", "200", "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err.startswith("./dev bench soak: --hours must be in (0, 168]")


def test_the_quick_folder_is_one_per_user(tmp_path, monkeypatch):
    """Another user's smoke-test folder on a shared machine (not writable for us) blocked ``--quick``."""
    import getpass
    import tempfile

    from trainer.measure import default_out

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.setattr(getpass, "getuser", lambda: "alice")
    alice = default_out(True)
    monkeypatch.setattr(getpass, "getuser", lambda: "bob/../x")
    assert alice.endswith("handover-bench-quick-alice") and default_out(True).endswith("handover-bench-quick-bob..x")

    def nameless():
        raise KeyError("uid not in the password database")

    monkeypatch.setattr(getpass, "getuser", nameless)
    assert default_out(True).endswith(f"handover-bench-quick-{os.getuid()}")


def test_decode_quick(tmp_path, capsys):
    printed, result = _run("decode", tmp_path, capsys, "--synthetic")
    assert result["synthetic"] is True and "--synthetic" in result["command"]
    for enc in ("rle", "raw"):
        assert result[enc]["frames"] == 400 and result[enc]["payload"]["frames_per_s_median"] > 0
    assert printed["rle_frames_per_s"] == result["rle_frames_per_s"]


def test_a_quick_run_never_overwrites_the_committed_results(tmp_path, monkeypatch, capsys):
    """``--quick`` without ``--out`` writes under the system's temp folder (a stranger's smoke test had
    rewritten results/latency.*, and its table then read like a measurement), and says it is one."""
    import tempfile

    from trainer.measure import default_out

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.chdir(tmp_path)
    assert bench(["decode", "--quick", "--quiet", "--synthetic"]) == 0
    out = Path(default_out(True))
    assert out.parent == tmp_path and out.name.startswith("handover-bench-quick-") and default_out(False) == "results"
    assert not (tmp_path / "results").exists()
    md = (out / "decode.md").read_text()
    assert "a smoke test, not a measurement" in md.splitlines()[2]
    assert "--out" not in json.loads((out / "decode.json").read_text())["command"]


@pytest.mark.slow
def test_inference_quick(tmp_path, capsys):
    printed, result = _run("inference", tmp_path, capsys)
    assert result["onnx_us"]["n"] == 200 and result["sklearn_us"]["n"] == 200
    assert printed["speedup_median"] == pytest.approx(result["speedup_median"])


@pytest.mark.slow
def test_ros2_quick(tmp_path, capsys):
    pytest.importorskip("rclpy", reason="needs a sourced ROS 2 (rclpy)")
    _printed, result = _run("ros2", tmp_path, capsys)
    assert result["events_received"] == result["events_sent"] > 0
    # pad images keep flowing; a starved subscriber (a busy machine) may miss a few of the last ones
    assert result["pad_images_received"] > 0 and result["pad_images_lost"] <= 0.02 * result["pad_images_published"]


def test_bench_an_unusable_out_folder_is_one_line_before_the_run(tmp_path, capsys, monkeypatch):
    """--out naming a file failed only after the benchmark ran, as `decode: [Errno 17] File exists`."""
    from runtime.cli import main as handover

    (tmp_path / "file").write_text("")
    for out in (tmp_path / "file", tmp_path / "file" / "below"):
        assert handover(["bench", "latency", "--quick", "--quiet", "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"handover bench: --out {out}: {tmp_path / 'file'} is a file, not a folder; choose a "
                              "folder") and err.count("\n") == 1, err  # was "cannot make that folder (File exists)"


def test_compare_records_its_out_folder_only_when_it_is_not_the_default(tmp_path, monkeypatch):
    """A ``--quick`` compare recorded its temp folder in its Reproduce line, a path of one machine."""
    import tempfile

    from benchmarks import compare_cli
    from trainer.measure import default_out

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    parser = argparse.ArgumentParser()
    compare_cli.add_arguments(parser)
    quick = parser.parse_args(["--quick"])
    quick.out = default_out(True)
    assert compare_cli.command_line(quick) == "./dev bench compare --quick --seed 0 --n-jobs 2"
    measured = parser.parse_args([])
    measured.out = "results"
    assert compare_cli.command_line(measured) == "./dev bench compare --seed 0 --n-jobs 2"
    elsewhere = parser.parse_args(["--out", str(tmp_path / "mine")])
    assert compare_cli.command_line(elsewhere).endswith(f"--out {tmp_path / 'mine'}")


def test_every_name_dev_bench_takes_is_a_module_and_every_study_has_a_name():
    import importlib.util

    from benchmarks import __main__ as suite

    names = [*suite.MODULES.values(), *suite.COMMANDS.values(), *(f"benchmarks.studies.{n}" for n in suite.STUDIES)]
    assert [n for n in names if importlib.util.find_spec(n) is None] == []
    studies = {p.stem for p in (Path(suite.__file__).parent / "studies").glob("*.py")} - {"__init__"}
    assert studies == set(suite.STUDIES)
