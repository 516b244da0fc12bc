"""``handover train --data rec/ --data field/``: a capture folder's confirmed events are trials of the
field's own subject, unconfirmed ones are skipped with one line, captured idle is dormant data
(synthetic capture folders, tests/capture_folder.py)."""

from __future__ import annotations

import json
import logging

import pytest

from firmware_io.recordings.field_capture import LABELS_FILE
from firmware_io.sim import simulate_protocol
from firmware_io.sim.idle import simulate_idle
from runtime.cli import main as handover
from tests.capture_folder import make_capture
from trainer.field_folder import field_recordings
from trainer.pipeline import _cases, load_or_simulate
from trainer.train_options import TrainOptions

ONE = {"poses": ("down",), "objects": ("ball",)}


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    """lab/: two simulated subjects; field/: 8 events of a third (6 confirmed), and 90 s of captured idle."""
    root = tmp_path_factory.mktemp("field")
    for rec in simulate_protocol(seed=4, n_subjects=2, runs=2, **ONE):
        rec.save(root / "lab" / f"subject_{rec.trials[0].subject}.hrec")
    third = simulate_protocol(seed=9, n_subjects=1, runs=2, **ONE)[0]
    truth = [t.action for t in third.trials]
    stems = make_capture(root / "field", third, ["pull"] * 8, [None] * 8, idle=simulate_idle(90.0, seed=2))
    (root / "field" / LABELS_FILE).write_text(json.dumps(dict(zip(stems[:6], truth[:6], strict=True))))
    return root, stems, truth


def test_confirmed_events_are_trials_of_the_field_and_the_rest_is_skipped_in_one_line(folders):
    root, stems, truth = folders
    said = []
    recs, names = field_recordings(root / "field", said.append)
    events = [r for r in recs if r.trials]
    assert [r.trials[0].action for r in events] == truth[:6]  # the label given, not the decision served (pull)
    assert {r.trials[0].subject for r in events} == {"field-robot1"}
    assert names[:6] == [f"{s}.hrec" for s in stems[:6]] and names[6].startswith("idle-")
    assert said == [f"{root / 'field'}: 2 of 8 captured events have no confirmed label and are skipped "
                    f"(run `handover review {root / 'field'}`)"]


def test_lab_and_field_folders_make_one_data_set_with_the_captured_idle_as_dormant(folders, caplog):
    root, _stems, truth = folders
    data = (str(root / "lab"), str(root / "field"))
    with caplog.at_level(logging.WARNING):
        recs, names, source, synthetic = load_or_simulate(data, 0, print)
    assert "2 of 8 captured events" in caplog.text
    assert len(recs) == 2 + 6 + 1 and names[0].startswith(str(root / "lab")) and synthetic
    assert source == f"2 recordings in {data[0]}, 7 recordings in {data[1]}"
    ds, idle = _cases(TrainOptions(data=data), recs, names, print)
    field = ds.groups == "field-robot1"
    assert set(ds.groups) >= {"s1", "s2", "field-robot1"}
    events = field & (ds.y != "dormant")
    assert sorted(ds.y[events]) == sorted(truth[:6])
    # each case is the window the daemon decided on (tests/capture_folder.py: report frame n // 2, T = 15)
    decided = [r.n_frames // 2 - 14 for r in recs if r.trials and r.trials[0].subject == "field-robot1"]
    assert ds.trigger_offsets[events].tolist() == decided
    assert idle is not None and set(idle.groups) == {"field-robot1"} and idle.seconds == pytest.approx(90, abs=2)


def test_data_given_twice_reads_both_and_the_same_folder_twice_is_refused(folders, tmp_path, capsys):
    root, _stems, _truth = folders
    from runtime.cli import OneLineParser
    from trainer.commands.train_cli import add_arguments, options_from_args

    parser = OneLineParser()
    add_arguments(parser)
    options = options_from_args(parser.parse_args(["--data", "a", "--data", "b"]))
    assert options.data == ("a", "b") and "--data a --data b" in options.command_line()
    assert TrainOptions(data="rec").data == ("rec",)
    lab = str(root / "lab")
    assert handover(["train", "--data", lab, "--data", lab + "/", "--out", str(tmp_path / "r"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "given twice" in err


def test_a_capture_folder_without_labels_or_idle_says_to_review(folders, tmp_path, capsys):
    root, _stems, _truth = folders
    third = simulate_protocol(seed=9, n_subjects=1, runs=1, **ONE)[0]
    make_capture(tmp_path / "new", third, ["pull"] * 2, ["taken", None])
    rc = handover(["train", "--data", str(root / "lab"), "--data", str(tmp_path / "new"), "--out",
                   str(tmp_path / "r"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and "handover review" in err[-1] and "no confirmed event" in err[-1]


def test_labels_of_events_no_longer_in_the_folder_are_named_in_one_line(folders, tmp_path):
    """An event max_mb removed (or a person moved) keeps its label: said, never silently dropped."""
    import shutil

    root, stems, truth = folders
    field = tmp_path / "field"
    shutil.copytree(root / "field", field)
    (field / f"{stems[0]}.hrec").unlink()
    said = []
    recs, _names = field_recordings(field, said.append)
    assert [r.trials[0].action for r in recs if r.trials] == truth[1:6]
    assert said[0] == f"{field / LABELS_FILE}: 1 label name no readable event here (removed by capture.max_mb, " \
                      "moved, or corrupt); not trained on"


def test_one_event_labelled_dormant_is_a_field_case_counted_with_the_idle_and_no_partial_subject(tmp_path):
    """A reviewed dormant event alone is one dormant case: it must not refuse training before the idle's
    dormant windows are counted, it is said as a field case (not "from idle"), and the capture folder's
    subject is no partial recording of a protocol."""
    from trainer.data_warnings import data_notes

    lab = simulate_protocol(seed=4, n_subjects=2, runs=2, **ONE)
    for rec in lab:
        rec.save(tmp_path / "lab" / f"subject_{rec.trials[0].subject}.hrec")
    idle_rec = simulate_idle(600.0, seed=3)
    idle_rec.meta = {**idle_rec.meta, "subject": "s1"}  # a lab subject with idle: the others could be partial
    idle_rec.save(tmp_path / "lab" / "idle_s1.hrec")
    third = simulate_protocol(seed=9, n_subjects=1, runs=1, **ONE)[0]
    stems = make_capture(tmp_path / "field", third, ["pull"] * 4, [None] * 4)
    (tmp_path / "field" / LABELS_FILE).write_text(json.dumps({stems[0]: "dormant", stems[1]: "push"}))
    data = (str(tmp_path / "lab"), str(tmp_path / "field"))
    recs, names, _source, _synthetic = load_or_simulate(data, 0, print)
    said = []
    ds, idle = _cases(TrainOptions(data=data), recs, names, said.append)
    assert idle is not None and idle.makes_class
    field = ds.groups == "field-robot1"
    assert ds.y[field].tolist().count("dormant") == 1
    assert "1 dormant case from the field: captured events a person labelled dormant (handover review)" in said
    counts = ds.counts()
    assert counts.dormant == len(idle.X) and counts.trials == int((ds.y != "dormant").sum()) + 1
    notes = data_notes(recs, names, idle)
    assert notes.partial == {"s2": "no idle"}  # the lab's rule still holds for lab subjects
