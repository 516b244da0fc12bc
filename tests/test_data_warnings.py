"""What the data can carry (trainer/data_warnings.py): a thin dormant class, one idle kind only and a
partial subject are said on train's console and in report.md (synthetic scripted subjects)."""

from __future__ import annotations

import contextlib
import io
import json

import pytest

from runtime.cli import main as handover
from tests.conftest import scripted_subjects
from trainer.data_warnings import FEW_DORMANT_WINDOWS, dormant_lines, planned_trials

TINY = ["--poses", "down", "--objects", "ball", "--auto", "--retries", "0", "--gap", "0", "--quiet", "--no-look"]


def record(out, subject: str, seed: int, *extra: str) -> int:
    return handover(["record", "--device", f"subject://?seed={seed}&speed=max", "--subject", subject,
                     "--out", str(out), *TINY, *extra])


def test_few_windows_state_the_number_and_why():
    lines = dormant_lines({"trigger:arm_move": 30, "trigger:regrasp": 17}, ["arm_move", "regrasp"])
    assert len(lines) == 1 and "rests on 47 windows" in lines[0] and f"fewer than {FEW_DORMANT_WINDOWS}" in lines[0]
    assert "6%" in lines[0] and "rule of three" in lines[0] and "--idle-only" in lines[0]
    assert dormant_lines({"trigger:arm_move": 80, "trigger:quiet": FEW_DORMANT_WINDOWS}, []) == []


def test_the_prior_s_dormant_windows_are_named_beside_the_lab_s():
    (line,) = dormant_lines({"trigger:arm_move": 200}, ["arm_move"], {"evidence:trigger:quiet": 40, "idle:trigger:arm_move": 60})
    assert line.startswith("the dormant class rests on 200 windows of your idle and 100 of the simulator's (the "
                           "product's prior: arm_move 60, quiet 40; another hand than yours): your idle gave one idle "
                           "kind only (its 200 windows are all arm_move)"), line


def test_one_idle_kind_names_present_missing_and_how_to_record():
    (line,) = dormant_lines({"trigger:arm_move": 200}, ["arm_move", "quiet", "regrasp"])
    assert "one idle kind only" in line and "all arm_move" in line
    assert "quiet, regrasp recorded but the trigger fired on none" in line
    assert "open, grasp, release not recorded" in line and "handover record --device URL --idle-only" in line


def test_planned_trials_read_from_the_last_session():
    meta = {"sessions": [{"protocol": {"poses": ["a"], "objects": ["b"], "actions": ["pull", "push"], "runs": 2}},
                         {"idle_plan": []}]}
    assert planned_trials(meta) == 4
    assert planned_trials({}) is None and planned_trials({"sessions": [{"protocol": "junk"}]}) is None


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """Two complete subjects with 3 min of idle, a third stopped after 3 of 8 trials (no idle)."""
    root = tmp_path_factory.mktemp("warn")
    data = root / "data"
    scripted_subjects(tmp_path_factory, data, {"s1": 0, "s2": 1})  # test_prior's first two, recorded once
    assert record(data, "s3", 2, "--runs", "2", "--max-trials", "3") == 0
    report = root / "report"
    with contextlib.redirect_stderr(io.StringIO()) as err:  # the console's lines, read by a test below
        code = handover(["train", "--data", str(data), "--out", str(report), "--no-sweep", "--repeats", "2",
                         "--no-replay", "--early", "off", "--quiet"])
    assert code == 0, err.getvalue()
    (root / "train.err").write_text(err.getvalue())
    return report


def test_train_says_what_the_dormant_class_rests_on_and_the_partial_subject(trained, capsys):
    metrics = json.loads((trained / "metrics.json").read_text())
    assert metrics["partial_subjects"] == {"s3": "3 of 8 planned trials, no idle"}
    notes = metrics["data_notes"]
    thin = [n for n in notes if "fewer than" in n]
    # the lab's windows and the prior's (simulated) that train the class too, both named when they are few
    lab, sim = metrics["idle"]["dormant_windows"], metrics["prior_dormant_windows"]
    assert sim > 0 and len(thin) == (lab < FEW_DORMANT_WINDOWS)
    for line in thin:
        assert line.startswith(f"the dormant class rests on {lab} windows of your idle and {sim} of the simulator's "
                               "(the product's prior: arm_move "), line
        assert f"fewer than {FEW_DORMANT_WINDOWS} of your own" in line
    assert any(n.startswith("s3 is a partial recording (3 of 8 planned trials, no idle)") for n in notes)
    text = (trained / "report.md").read_text()
    for n in notes:
        assert n in text
    row = next(line for line in text.splitlines() if line.startswith("| s3 |"))
    assert "partial recording (3 of 8 planned trials, no idle)" in row and "of 3 cases right" in row
    assert "%" not in row


def test_console_names_them_even_when_quiet(trained):
    err = (trained.parent / "train.err").read_text()  # the fixture's train, with --quiet
    assert "handover train: s3 is a partial recording (3 of 8 planned trials, no idle)" in err
    notes = json.loads((trained / "metrics.json").read_text())["data_notes"]
    assert all(f"handover train: {n}" in err for n in notes)


def test_idle_imported_at_another_rate_does_not_set_the_models_rate(trained):
    """70 Hz idle (the real recordings' frequency-analysis files) beside 32 Hz trials: the data set keeps 32 Hz."""
    from firmware_io.recordings.recording import Recording
    from trainer.dataset import build_dataset

    rec = Recording.load(trained.parent / "data" / "subject_s1.hrec")
    fast = Recording(rec.layout, rec.frames, rec.timestamps[0] + (rec.timestamps - rec.timestamps[0]) * 32 / 70, [],
                     {"subject": "idle70"})
    ds = build_dataset([rec, fast, fast, fast])
    assert abs(ds.sample_rate_hz - 1 / rec.sample_interval()) < 0.5


def test_the_replay_table_marks_a_partial_subject():
    from trainer.report import _replay_lines

    fold = {"events": 3, "right": 3, "wrong": 0, "missed": 0, "idle_hours": 0.0, "false_events": 0,
            "false_per_hour": None}
    replay = {"mode": "onset_dormant", "folds": [{"held_out": "s1", **fold}, {"held_out": "s3", **fold}],
              "events": 6, "right": 6, "wrong": 0, "missed": 0, "right_fraction": 1.0, "early_reports": 0,
              "onset_to_report_frames": None, "reference": ["onset"], "idle_hours": 0.0, "idle_by_source": {}}
    lines = _replay_lines({"own_replay": replay, "partial_subjects": {"s3": "3 of 8 planned trials, no idle"}}, "x")
    assert any(line.startswith("| s3 (partial: 3 of 8 planned trials, no idle) | 3 |") for line in lines)
    assert any(line.startswith("| s1 | 3 |") for line in lines)


def test_too_few_for_the_split_names_the_short_class_and_how_to_get_more():
    from collections import Counter

    from trainer.pipeline import _split_problem

    line = _split_problem(Counter(bump=27, dormant=1, hold=27, pull=27, push=27))
    assert "dormant is short" in line and "label more captured events dormant" in line and "--runs" not in line
    line = _split_problem(Counter(bump=27, dormant=30, hold=1, pull=27, push=27))
    assert "record more runs of hold (handover record --runs)" in line and "dormant" not in line.split(";")[-1]


def test_suggested_record_commands_carry_device_and_out():
    from trainer.data_warnings import MORE_IDLE
    from trainer.recorded_idle import too_few_line

    for text in (MORE_IDLE, too_few_line(60.0, 3, "trigger")):
        assert "`handover record --device URL --idle-only" in text and "--out DIR`" in text


def test_recordings_of_another_simulated_lab_than_the_prior_are_said_once():
    from types import SimpleNamespace as Rec

    from firmware_io.sim.lab import DEFAULT_LAB
    from trainer.data_warnings import data_notes, prior_lab_line
    from trainer.prior import PRIOR_LAB

    assert PRIOR_LAB == DEFAULT_LAB
    lab_b = [Rec(meta={"synthetic": True, "lab": "B"}, trials=[]), Rec(meta={}, trials=[])]
    line = prior_lab_line(lab_b, PRIOR_LAB)
    assert line.startswith("the recordings come from simulated lab B and the product's prior is simulated lab A")
    assert prior_lab_line([Rec(meta={"synthetic": True}, trials=[]), Rec(meta={}, trials=[])], PRIOR_LAB) is None
    mixed = prior_lab_line([*lab_b, Rec(meta={"synthetic": True}, trials=[])], PRIOR_LAB)  # said, not "the recordings"
    assert mixed.startswith("1 of 2 simulated recordings come from simulated lab B")
    assert line in data_notes(lab_b, ["a", "b"], None, prior_lab=PRIOR_LAB).lines
    assert data_notes(lab_b, ["a", "b"], None).lines == []  # --no-prior: nothing to say
