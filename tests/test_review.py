"""``handover review``: one keystroke confirms or corrects a captured event's label, labels.json is
written after each answer, bad folders and files are one line each (synthetic capture folders)."""

from __future__ import annotations

import io
import json

import pytest

from firmware_io.recordings.field_capture import LABELS_FILE
from firmware_io.sim import simulate_protocol
from runtime.cli import main as handover
from tests.capture_folder import make_capture
from trainer.commands.review_cli import review
from trainer.field_folder import FieldFolderError, read_labels


@pytest.fixture(scope="module")
def protocol():
    return simulate_protocol(seed=3, n_subjects=1, runs=1, poses=("down",), objects=("ball",))[0]


@pytest.fixture
def capture(tmp_path, protocol):
    folder = tmp_path / "field"
    stems = make_capture(folder, protocol, ["pull", "push", "hold", "bump"], ["taken", None, "kept", "dropped"])
    return folder, stems


def keys(text: str):
    """A fake keyboard: one character per call, then the end of input."""
    it = iter(text)
    return lambda: next(it, "")


def run_review(folder, typed: str, **kw) -> tuple[dict, str, list[str]]:
    out, said = io.StringIO(), []
    labels = review(folder, keys(typed), out, said.append, **kw)
    return labels, out.getvalue(), said


def test_one_key_confirms_another_corrects_and_q_keeps_what_was_answered(capture):
    folder, stems = capture
    # event 1 proposes pull (taken): Enter confirms; event 2 proposes nothing: 3 says hold; then q
    labels, shown, _ = run_review(folder, "\n3q")
    assert labels == {stems[0]: "pull", stems[1]: "hold"}
    assert read_labels(folder) == labels  # written, not only returned
    assert "Enter: pull" in shown and "decided push" in shown and "f1 dist" in shown  # the quick look
    # a second review asks only the unlabelled: event 3 (kept: not a pull) proposes nothing, d labels it dormant; s skips 4
    labels, shown, _ = run_review(folder, "ds")
    assert labels[stems[2]] == "dormant" and stems[3] not in labels
    assert shown.startswith("2 of 4 captured events")


def test_enter_confirms_the_decision_without_a_proposal_and_unknown_keys_ask_again(capture, tmp_path, protocol):
    folder, stems = capture
    labels, shown, _ = run_review(folder, "s\nsx2")  # 2 (nothing said): Enter = its decision; 4: x refused, 2
    assert labels == {stems[1]: "push", stems[3]: "push"}
    assert "Enter: push (decided)" in shown and "Enter: bump (decided)" in shown and "key 'x'" in shown
    other = tmp_path / "other"  # a decision no class key names (another model's class): Enter is not enough
    make_capture(other, protocol, ["wave"], [None])
    labels, shown, _ = run_review(other, "\nd")
    assert list(labels.values()) == ["dormant"] and "no label shown" in shown


def test_ctrl_c_loses_no_answer_given(capture):
    folder, stems = capture
    typed = iter("\n1")

    def key() -> str:  # Enter, 1, then Ctrl-C at the third event
        if (k := next(typed, None)) is None:
            raise KeyboardInterrupt
        return k

    with pytest.raises(KeyboardInterrupt):
        review(folder, key, io.StringIO(), print)
    assert read_labels(folder) == {stems[0]: "pull", stems[1]: "pull"}


def test_accept_outcomes_labels_every_proposal_and_keeps_given_labels(capture, capsys):
    folder, stems = capture
    (folder / LABELS_FILE).write_text(json.dumps({stems[2]: "push"}))
    assert handover(["review", str(folder), "--accept-outcomes"]) == 0
    # taken -> pull; nothing said -> none; kept -> none (a person said push); dropped -> none
    assert read_labels(folder) == {stems[0]: "pull", stems[2]: "push"}
    assert "1 events labelled from their outcomes" in capsys.readouterr().out
    assert handover(["review", str(folder), "--list"]) == 0
    listed = capsys.readouterr().out.splitlines()
    assert len(listed) == 4 and "outcome taken" in listed[0] and listed[0].endswith("label pull")


def test_bad_input_is_one_line_each(capture, tmp_path, capsys):
    folder, stems = capture
    assert handover(["review", str(tmp_path / "nowhere", ), "--list"]) == 2
    (tmp_path / "lab").mkdir()
    assert handover(["review", str(tmp_path / "lab"), "--list"]) == 2
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 2 and "no such folder" in errors[0] and "not a capture folder" in errors[1]
    (folder / f"{stems[1]}.hrec").write_bytes(b"PK\x03\x04 not a zip")
    assert handover(["review", str(folder), "--list"]) == 0
    out = capsys.readouterr()
    assert len(out.out.splitlines()) == 3 and out.err.count("\n") == 1 and stems[1] in out.err
    (folder / LABELS_FILE).write_text("{not json")
    assert handover(["review", str(folder), "--accept-outcomes"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "labels.json" in err and "not overwritten" in err
    assert (folder / LABELS_FILE).read_text() == "{not json"
    (folder / LABELS_FILE).write_text(json.dumps({stems[0]: "wave"}))
    with pytest.raises(FieldFolderError, match="one of pull, push, hold, bump, dormant"):
        read_labels(folder)


def test_plot_writes_a_figure_of_each_event_asked_about(capture, tmp_path):
    folder, stems = capture
    _labels, shown, _ = run_review(folder, "sq", plot=tmp_path / "figs")
    assert sorted(p.name for p in (tmp_path / "figs").iterdir()) == [f"{stems[0]}.png", f"{stems[1]}.png"]
    assert str(tmp_path / "figs" / f"{stems[0]}.png") in shown


def test_a_plot_folder_that_cannot_be_written_is_one_line(capture, tmp_path, capsys, monkeypatch):
    folder, _stems = capture
    (tmp_path / "file").write_text("")
    monkeypatch.setattr("sys.stdin", io.StringIO("sq"))
    assert handover(["review", str(folder), "--plot", str(tmp_path / "file")]) == 2  # was a FileExistsError traceback
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--plot" in err and "give a folder you can write" in err


def test_a_window_decided_dormant_is_listed_as_unreported_and_waits_for_a_person(tmp_path, protocol, capsys):
    folder = tmp_path / "field"
    stems = make_capture(folder, protocol, ["pull", "dormant"], ["taken", None], unreported=(1,))
    assert handover(["review", str(folder), "--accept-outcomes"]) == 0
    assert read_labels(folder) == {stems[0]: "pull"}  # the robot said nothing about the dormant window
    assert handover(["review", str(folder), "--list"]) == 0
    listed = capsys.readouterr().out.splitlines()[-2:]
    assert "   decided pull" in listed[0] and "unreported dormant" in listed[1]
    labels, shown, _ = run_review(folder, "3")  # a person: it was a hold the serving model missed
    assert labels[stems[1]] == "hold" and "Enter: dormant (decided)" in shown


def test_a_hostile_capture_never_reaches_the_terminal_nor_crashes_nor_hangs(capture, capsys):
    """A capture's metadata, outcomes and file names are data, not text for the terminal: junk is shown as
    unknown, a FIFO is refused in one line (it hung review), a far time is "?" (it was a traceback)."""
    import os
    import shutil

    from firmware_io.recordings.field_capture import META_KEY, OUTCOMES_FILE
    from firmware_io.recordings.recording import Recording

    folder, stems = capture
    path = folder / f"{stems[0]}.hrec"
    rec = Recording.load(path)
    rec.meta = {**rec.meta, META_KEY: {**rec.meta[META_KEY], "class": "\x1b[2Jpwned", "time": 1e300}}
    rec.save(path)
    shutil.copy(path, folder / "event-\x1b[31m.hrec")
    with open(folder / OUTCOMES_FILE, "a") as fh:
        fh.write(json.dumps({"event": stems[1], "outcome": "\x1b[2J" + "x" * 100}) + "\n")
    os.mkfifo(folder / "event-000000001-1800000000000.hrec")
    assert handover(["review", str(folder), "--list"]) == 0
    out = capsys.readouterr()
    assert "\x1b" not in out.out + out.err and len(out.out.splitlines()) == 4
    assert out.out.splitlines()[0].split()[1:3] == ["?", "decided"] and "pull" in out.out.splitlines()[0]
    assert "1 unreadable line" in out.err
    os.mkfifo(folder / LABELS_FILE)
    assert handover(["review", str(folder), "--list"]) == 2
    assert "not a regular file" in capsys.readouterr().err


def test_kept_proposes_no_label_because_it_cannot_tell_push_hold_or_bump_apart():
    """Confirming the decision on ``kept`` turned a serving model's hold-read-as-bump into a bump label."""
    from firmware_io.recordings.field_capture import proposed_label
    classes = ("pull", "push", "hold", "bump", "dormant")
    assert [proposed_label("bump", w, classes) for w in ("kept", "dropped", None, "taken", "hold")] == \
        [None, None, None, "pull", "hold"]
