"""A lab's own model end to end: ``handover record`` with idle stretches against scripted simulated
subjects (``subject://``, synthetic), ``handover train`` with the dormant class and the held-out
replay through the daemon, ``handover demo --model`` on the demo's scripted session.

The fast tests use tiny protocols (one pose, one object); the slow one records three subjects'
short protocol plus the default idle and holds the trained model to the demo's bar."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from firmware_io.recordings.idle_stretches import CYCLE, SOURCES, idle_plan, stretches_of
from firmware_io.recordings.recording import Recording
from runtime.cli import main as handover
from tests.conftest import SCRIPTED_IDLE_MINUTES, scripted_subjects

TINY = ["--poses", "down", "--objects", "ball", "--auto", "--retries", "0", "--gap", "0", "--quiet", "--no-look"]


def record(out, subject: str, seed: int, *extra: str, device_extra: str = "") -> int:
    return handover(["record", "--device", f"subject://?seed={seed}&speed=max{device_extra}", "--subject", subject,
                     "--out", str(out), *TINY, *extra])


def test_idle_plan_keeps_the_mix_at_any_length():
    """A plan repeats the round of stretches: every kind in a round's length, arm moves twice."""
    round_s = sum(s for _, s in CYCLE)
    plan = idle_plan(round_s / 60.0)
    assert [s.source for s in plan] == [c[0] for c in CYCLE]
    assert {s.source for s in plan} == set(SOURCES)
    assert len(idle_plan(3 * round_s / 60.0)) == 3 * len(CYCLE)
    assert idle_plan(0) == []
    with pytest.raises(ValueError):
        idle_plan(-1)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """Two scripted subjects (4 actions x 2 runs each) with three minutes of idle (test_prior's and
    test_data_warnings' first two, recorded once), and one idle-only session."""
    out = scripted_subjects(tmp_path_factory, tmp_path_factory.mktemp("own") / "data", {"s1": 0, "s2": 1})
    assert record(out, "idle1", 5, "--idle-only", "--idle-minutes", "1") == 0
    return out


def test_recorded_idle_stretches_are_labelled_like_the_simulators(recorded):
    rec = Recording.load(recorded / "subject_s1.hrec")
    assert len(rec.trials) == 8
    stretches = stretches_of(rec.meta)
    assert [s["source"] for s in stretches] == [s.source for s in idle_plan(SCRIPTED_IDLE_MINUTES)]
    assert rec.meta["sources"] == list(SOURCES)
    code = np.asarray(rec.meta["source_codes"])
    for tr in rec.trials:
        assert (code[tr.first:tr.last + 1] == -1).all()
    for s in stretches:
        assert (code[s["first"]:s["last"] + 1] == SOURCES.index(s["source"])).all()
        n = s["last"] - s["first"] + 1
        assert abs(n / 32.0 - s["seconds"]) < 0.5, "each stretch holds its seconds of frames"
    only = Recording.load(recorded / "subject_idle1.hrec")
    assert only.trials == [] and len(stretches_of(only.meta)) >= 2


def test_idle_resumes_after_the_device_is_lost_and_loses_nothing(tmp_path, capsys):
    """Unplugged during the idle stretches: what was saved stays, the same command records the rest."""
    out = tmp_path / "data"
    code = record(out, "s1", 3, "--runs", "1", "--idle-minutes", "0.5", device_extra="&unplug_idle=3")
    assert code != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "run the same command again" in err[0]
    before = Recording.load(out / "subject_s1.hrec")
    kept = [(s["index"], s["source"], s["last"] - s["first"]) for s in stretches_of(before.meta)]
    frames = {s["index"]: before.frames[s["first"]:s["last"] + 1].copy() for s in stretches_of(before.meta)}
    assert record(out, "s1", 3, "--runs", "1", "--idle-minutes", "0.5") == 0
    after = Recording.load(out / "subject_s1.hrec")
    assert len(after.trials) == 4
    done = stretches_of(after.meta)
    assert [s["index"] for s in done] == list(range(len(idle_plan(0.5))))
    for s in done:
        if s["index"] in frames:
            assert (after.frames[s["first"]:s["last"] + 1] == frames[s["index"]]).all()
    assert {(s["index"], s["source"], s["last"] - s["first"]) for s in done} >= set(kept)


def test_idle_only_with_no_minutes_is_one_line(tmp_path, capsys):
    assert record(tmp_path, "s1", 0, "--idle-only", "--idle-minutes", "0") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--idle-only" in err[0]


@pytest.mark.parametrize("minutes", ["nan", "inf", "1e12", "-1"])
def test_idle_minutes_that_plan_nothing_or_forever_are_one_line(tmp_path, capsys, minutes):
    """NaN recorded nothing and said the session was complete; infinity never started (the plan was endless)."""
    assert record(tmp_path, "s1", 0, "--idle-only", "--idle-minutes", minutes) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--idle-minutes" in err[0] and "from 0 to" in err[0]
    assert not list(tmp_path.iterdir())


def test_train_on_only_idle_is_one_line(recorded, tmp_path, capsys):
    data = tmp_path / "only"
    data.mkdir()
    (data / "subject_idle1.hrec").write_bytes((recorded / "subject_idle1.hrec").read_bytes())
    code = handover(["train", "--data", str(data), "--out", str(tmp_path / "r"), "--no-sweep", "--quiet"])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "only idle" in err[0] and "handover record" in err[0]


def test_a_stretch_shorter_than_a_window_is_named_and_the_rest_is_kept(recorded):
    """One line for the short stretch; every other stretch still gives its windows."""
    from trainer.dataset import build_dataset
    from trainer.recorded_idle import recorded_idle_windows

    rec = Recording.load(recorded / "subject_s1.hrec")
    ds = build_dataset([rec])
    full = recorded_idle_windows([rec], ["s1.hrec"], ds, seed=0, cut="in_view")
    stretches = stretches_of(rec.meta)
    short = dict(stretches[1], last=stretches[1]["first"] + 5)
    cut = Recording(rec.layout, rec.frames, rec.timestamps, rec.trials,
                    {**rec.meta, "idle_stretches": [stretches[0], short, *stretches[2:]]})
    got = recorded_idle_windows([cut], ["s1.hrec"], ds, seed=0, cut="in_view")
    assert len(got.notes) == 1 and "shorter than a window" in got.notes[0] and "6 frames" in got.notes[0]
    lost = stretches[1]["source"]
    assert len(got.X) > 0
    assert set(got.per_source) >= set(full.per_source) - {f"idle:{lost}"}
    assert set(got.groups.tolist()) == {"s1"}


def test_idle_too_short_for_the_class_is_said_in_the_report_not_called_none(recorded, tmp_path):
    """Every stretch cut below a window: training says what to record and the report does not say
    "idle recorded: none"; the model has no dormant class and claims no dormant cut."""
    from runtime.model import load_model
    from trainer.recorded_idle import too_few_line

    data = tmp_path / "short"
    data.mkdir()
    for name in ("s1", "s2"):
        rec = Recording.load(recorded / f"subject_{name}.hrec")
        short = [dict(st, last=st["first"] + 5) for st in stretches_of(rec.meta)]
        Recording(rec.layout, rec.frames, rec.timestamps, rec.trials,
                  {**rec.meta, "idle_stretches": short}).save(data / f"subject_{name}.hrec")
    report = tmp_path / "report"
    assert handover(["train", "--data", str(data), "--out", str(report), "--no-sweep", "--repeats", "2",
                     "--no-replay", "--no-prior", "--quiet"]) == 0  # the idle is the question, not the prior
    idle = json.loads((report / "metrics.json").read_text())["idle"]
    assert idle["dormant_class"] is False and idle["dormant_windows"] == 0 and idle["seconds"] > 0
    text = (report / "report.md").read_text()
    assert "idle recorded: none" not in text
    assert f"- idle recorded: {too_few_line(idle['seconds'], 0, idle['cut'])}" in text
    model = load_model(report / "model.onnx")
    assert model.meta.dormant_class is None and "dormant_cut" not in model.meta.training


def test_without_idle_one_line_reads_the_measured_cost(tmp_path):
    """The figure comes from results/streams.json (read, not written into the code)."""
    from trainer.recorded_idle import STREAMS_RESULTS, no_idle_line

    fake = tmp_path / "streams.json"
    fake.write_text(json.dumps({"sim_false_per_hour": {"onset": 123.4, "onset_dormant": 5.6}}))
    line = no_idle_line(fake)
    assert "123 false events per hour" in line and "6 with a dormant class" in line and "--idle-only" in line
    measured = json.loads(STREAMS_RESULTS.read_text())["sim_false_per_hour"]["onset"]
    assert f"{measured:.0f} false events" in no_idle_line()
    assert "\n" not in no_idle_line(tmp_path / "missing.json")


@pytest.fixture(scope="module")
def trained(recorded, tmp_path_factory):
    report = tmp_path_factory.mktemp("own") / "report"
    code = handover(["train", "--data", str(recorded), "--out", str(report), "--no-sweep", "--repeats", "2",
                     "--quiet"])
    assert code == 0
    return report


def test_train_on_recordings_with_idle_exports_a_dormant_class_and_replays(trained):
    from runtime.model import load_model

    model = load_model(trained / "model.onnx")
    assert model.meta.dormant_class == "dormant" and "dormant" in model.meta.classes
    assert model.meta.trigger["kind"] == "onset"
    metrics = json.loads((trained / "metrics.json").read_text())
    replay = metrics["own_replay"]
    assert replay["mode"] == "onset_dormant"
    assert [f["held_out"] for f in replay["folds"]] == ["idle1", "s1", "s2"]
    assert replay["events"] == 16 == replay["right"] + replay["wrong"] + replay["missed"]
    assert replay["idle_hours"] > 0 and set(replay["idle_by_source"]) <= set(SOURCES)
    text = (trained / "report.md").read_text()
    assert "## Stream replay of held-out subjects" in text and "idle recorded:" in text
    assert "Bag-of-Words" not in text.splitlines()[0] and "words" not in text.split("## Model")[1].split("##")[0]


def test_inspect_says_which_stream_settings_the_model_serves(trained, capsys):
    assert handover(["inspect", str(trained / "model.onnx")]) == 0
    out = capsys.readouterr().out
    assert "stream settings: onset_dormant" in out and "dormant class: dormant" in out


def test_inspect_and_the_train_report_count_the_same_windows(trained, capsys):
    """The card printed the labelled trials as "windows" (16) while the report counted the trials'
    windows plus the dormant ones; both now say the trainer's own counts in one wording."""
    import re

    metrics = json.loads((trained / "metrics.json").read_text())
    dormant = metrics["dataset"]["per_class"]["dormant"]
    assert dormant > 0 and metrics["n_cases"] == metrics["n_trials"] + dormant
    assert handover(["inspect", str(trained / "model.onnx")]) == 0
    card = re.search(r"trained on: (.*?), data ", capsys.readouterr().out).group(1)
    assert card == (f"{metrics['n_cases']} windows: {metrics['n_trials']} from {metrics['n_trials']} labelled "
                    f"trials + {dormant} dormant windows from idle; plus {metrics['prior_windows']} simulated windows "
                    f"of the product's prior ({metrics['prior_dormant_windows']} dormant)")  # what came from where
    assert metrics["prior_windows"] > metrics["prior_dormant_windows"] > 0
    assert f"- trained on {card}\n" in (trained / "report.md").read_text()


def test_demo_scores_a_given_model(trained, tmp_path, capsys):
    code = handover(["demo", "--model", str(trained / "model.onnx"), "--speed", "max", "--json", "--events", "8",
                     "--out", str(tmp_path / "demo")])
    assert code == 0
    out, err = capsys.readouterr()
    summary = json.loads(out)
    assert summary["setting"] == "onset_dormant" and summary["events_expected"] == 8
    assert summary["model"] == str(trained / "model.onnx")
    steps = [line[:6] for line in err.splitlines() if line.startswith("[")]
    assert steps[:3] == ["[1-2/4", "[3/4] ", "[4/4] "], err  # a given model's steps start at the first, not at [3/4]
    assert "no simulation, no training), served in setting onset_dormant" in err
    from benchmarks.session_spread import spread  # the bench's in-process replay scores the session as the demo does

    same = spread(trained / "model.onnx", None, seeds=(0,), events=8)
    assert (same["right"], same["missed"], same["outside"]) == (
        summary["events_correct"], summary["events_missed"], summary["false_events"]), (same, summary)
    assert same["sessions"][0]["p90"] == summary["report_minus_onset_frames"]["p90"] and same["right"] >= 6


def test_demo_with_a_model_that_is_not_one_is_one_line(tmp_path, capsys):
    bad = tmp_path / "model.onnx"
    bad.write_bytes(b"not a model")
    assert handover(["demo", "--model", str(bad), "--speed", "max", "--out", str(tmp_path / "d")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--model" in err[0]


@pytest.mark.slow
@pytest.mark.timeout(1500)  # three recordings, training with early heads and the replay, the demo: minutes
def test_three_recorded_subjects_train_a_model_that_passes_the_demo(tmp_path, capsys):
    """The lab's path: 3 scripted subjects (short protocol: 3 runs, plus the default idle), train,
    then the demo's scripted session of 40 events by unseen subjects (synthetic)."""
    data = tmp_path / "data"
    for k in range(3):
        assert handover(["record", "--device", f"subject://?seed={k}&speed=max", "--subject", f"s{k}", "--out",
                         str(data), "--runs", "3", "--auto", "--retries", "0", "--gap", "0", "--quiet",
                         "--no-look"]) == 0
    report = tmp_path / "report"
    assert handover(["train", "--data", str(data), "--out", str(report), "--no-sweep", "--repeats", "2",
                     "--quiet"]) == 0
    capsys.readouterr()
    assert handover(["demo", "--model", str(report / "model.onnx"), "--speed", "max", "--json", "--out",
                     str(tmp_path / "demo")]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["events_expected"] == 40
    assert summary["events_correct"] >= 38, summary
    assert summary["false_events"] == 0
    assert summary["report_minus_onset_frames"]["median"] <= 7, "early decisions fire on a lab's model"
    assert json.loads((report / "metrics.json").read_text())["own_replay"]["events"] == 324


def test_import_names_the_recorders_idle_sources():
    from firmware_io.commands.import_cli import IDLE_SOURCES

    assert IDLE_SOURCES == SOURCES


def test_import_marks_a_recording_as_idle(tmp_path, capsys):
    """A .dsa file imported with --idle is one idle stretch; training cuts dormant windows from it."""
    from trainer.shared_data import default_data_dir

    sources = sorted(default_data_dir().rglob("*.dsa")) if default_data_dir().is_dir() else []
    if not sources:
        pytest.skip(f"no real .dsa recordings in {default_data_dir()}")
    src = sources[0]
    assert handover(["import", str(src), "--out", str(tmp_path), "--idle", "arm_move", "--subject", "robot1"]) == 0
    assert "idle (arm_move)" in capsys.readouterr().out
    (rec_path,) = tmp_path.glob("*.hrec")
    rec = Recording.load(rec_path)
    (stretch,) = stretches_of(rec.meta)
    assert (stretch["first"], stretch["last"], stretch["source"]) == (0, rec.n_frames - 1, "arm_move")
    assert rec.meta["subject"] == "robot1" and set(rec.meta["source_codes"]) == {SOURCES.index("arm_move")}
    assert handover(["import", str(src), "--out", str(tmp_path / "x"), "--subject", "robot1"]) == 2
    assert "--idle" in capsys.readouterr().err


def test_real_idle_recordings_are_scored_for_real_data_or_when_asked(tmp_path, monkeypatch):
    from trainer.pipeline import scores_real_idle

    monkeypatch.setenv("HANDOVER_SHARED_DATA", str(tmp_path))
    assert scores_real_idle(None, synthetic=False) and scores_real_idle(True, synthetic=True)
    assert not scores_real_idle(None, synthetic=True) and not scores_real_idle(False, synthetic=False)
    monkeypatch.setenv("HANDOVER_SHARED_DATA", str(tmp_path / "absent"))
    assert not scores_real_idle(True, synthetic=False)


def test_the_docs_quote_the_one_figure_train_prints_for_a_model_without_dormant_class():
    """One comparison, one figure (results/streams.json), the same in train's line, the README and the docs."""
    from trainer.recorded_idle import no_dormant_cost, no_idle_line

    cost = no_dormant_cost()
    assert cost is not None and cost in no_idle_line()
    root = Path(__file__).resolve().parents[1]
    for doc in ("README.md", "docs/OWN_MODEL.md", "docs/GUIDE.md"):
        assert cost in " ".join((root / doc).read_text().split()), doc
