"""handover record / plot against the emulated controller with a scripted simulated subject (synthetic data).

Sessions are short (1 pose x 1 object x 4 actions x 1 run, 2 s trials) and the emulator runs
at 40x real time (the unplug test at 10x), so a whole session takes well under a second of wall time.
"""

from __future__ import annotations

import io
import sys
from collections.abc import Callable

import numpy as np
import pytest

from firmware_io.client import DSAClient
from firmware_io.layout import SensorLayout
from firmware_io.recordings.record_session import (
    ProtocolPlan,
    SessionError,
    SessionIO,
    SessionOptions,
    SessionStore,
    check_trigger,
    flagged_trials,
    recording_path,
    run_session,
)
from firmware_io.recordings.recording import ACTIONS, Recording
from firmware_io.recordings.terminal_view import sparkline, trial_view
from firmware_io.recordings.trial_capture import LEAD_IN_SECONDS
from firmware_io.sim.scripted_subject import ScriptedSubject
from runtime.cli import main as handover

SPEED = 40.0
SHORT = ["--poses", "down", "--objects", "ball", "--runs", "1", "--trial-seconds", "2", "--gap", "0",
         "--countdown", "0", "--quiet", "--idle-minutes", "0"]
PLAN = ProtocolPlan(("down",), ("ball",), ACTIONS, 1)
KEYS = {("down", "ball", a, 1) for a in ACTIONS}


def record(tmp_path, *extra, device=f"subject://?seed=3&speed={SPEED}", subject="s1") -> int:
    return handover(["record", "--device", device, "--subject", subject, "--out", str(tmp_path), *SHORT, *extra])


def keys(rec: Recording) -> list[tuple]:
    return [(t.pose, t.object, t.action, t.run) for t in rec.trials]


def open_session(tmp_path, subject: ScriptedSubject, **client_kw):
    client = DSAClient(subject.connect, **client_kw)
    layout = client.open()
    client.start()
    return client, SessionStore.open(recording_path(tmp_path, "s1"), "s1", layout)


def auto_opts(**kw) -> SessionOptions:
    base = {"trial_seconds": 2.0, "gap_seconds": 0.0, "auto": True, "retries": 0}
    base.update(kw)
    return SessionOptions(**base)


def training_cuts(rec: Recording) -> dict[tuple, int]:
    """Each trial's frame ``handover train`` cuts its case at, by (pose, object, action, run)."""
    from trainer.dataset import build_dataset, dataset_trigger, frames_before_trigger
    from trainer.defaults import DEFAULT_MODEL

    T, settings = int(DEFAULT_MODEL["T"]), dataset_trigger()
    ds = build_dataset([rec], T=T, trigger=settings)
    return {(p, o, a, int(r)): int(s) + frames_before_trigger(settings, T)
            for p, o, a, r, s in zip(ds.poses, ds.objects, ds.y, ds.runs, ds.trigger_offsets, strict=True)}


def assert_consistent(rec: Recording) -> None:
    """Every stored flag agrees with the frames: what the recorder said is what the file holds, and the
    trigger it marked is the frame training cuts at (the paper's level where no training cut judged)."""
    cuts = training_cuts(rec) if any("case_cut" in t.extra for t in rec.trials) else {}
    for t in rec.trials:
        frames, stamps = rec.trial_frames(t)
        check = check_trigger(frames, rec.layout)
        assert t.extra["triggered"] == check.triggered
        expected = cuts.get((t.pose, t.object, t.action, t.run), -1) if "case_cut" in t.extra else check.first_frame
        assert t.extra["trigger_frame"] == expected, (t.action, t.extra["trigger_frame"], expected)
        assert 87 <= t.n_frames <= 102  # 1 s held grasp before go + 2 s after, at ~32 Hz
        assert 28 <= t.extra["go_frame"] <= 34 and t.extra["lead_in_s"] == LEAD_IN_SECONDS
        if t.extra.get("onset") is not None:  # the person acts after go, not in the lead-in
            assert t.extra["onset"] > t.extra["go_frame"]
        assert np.all(np.diff(stamps) > 0)


# -- plan, trigger, terminal view ---------------------------------------------------------------
def test_default_plan_is_the_papers_protocol():
    slots = ProtocolPlan().slots()
    assert len(slots) == 3 * 3 * 4 * 5
    assert len(set(slots)) == len(slots)
    assert slots[0].key == ("down", "ball", "pull", 1) and slots[1].key == ("down", "ball", "pull", 2)


@pytest.mark.parametrize("kw", [{"runs": 0}, {"poses": ()}, {"actions": ("pull", "pull")}, {"objects": ("a b",)}])
def test_bad_plan_names_the_problem(kw):
    with pytest.raises(SessionError):
        ProtocolPlan(**kw)


def test_trigger_check_uses_fifteen_percent_of_full_scale():
    layout = SensorLayout.sdh2()
    frames = np.zeros((10, layout.n_taxels), np.uint16)
    level = 0.15 * 4095
    frames[4, 100] = int(np.ceil(level)) - 1
    assert not check_trigger(frames, layout).triggered
    frames[6, 100] = int(np.ceil(level))
    check = check_trigger(frames, layout)
    assert check.triggered and check.first_frame == 6
    distal_only = check_trigger(frames, layout, pads="distal")  # column 100 is on pad 1 (distal, from 84)
    assert distal_only.triggered
    assert not check_trigger(frames, layout, pads="proximal").triggered


def test_sparkline_shares_a_scale_and_squeezes_to_width():
    assert sparkline([0, 1, 2, 4], top=4) == " ▂▄█"
    assert sparkline(np.arange(1000), width=20)[-1] == "█"
    assert len(sparkline(np.arange(1000), width=20)) == 20
    layout = SensorLayout.sdh2()
    frames = np.zeros((30, layout.n_taxels), np.uint16)
    frames[10:20, layout.matrix_slice(3)] = 500
    view = trial_view(frames, layout, trigger_frame=10).splitlines()
    assert len(view) == layout.n_matrices + 1
    assert "█" in view[3] and "█" not in view[0]


# -- sessions -------------------------------------------------------------------------------------
def test_full_short_session_records_every_trial_once(tmp_path, capsys):
    assert record(tmp_path, "--auto") == 0
    out = capsys.readouterr().out.strip().splitlines()  # --quiet --auto: the final summary line only
    assert len(out) == 1 and out[0].startswith("session complete: 4 trials"), out
    rec = Recording.load(tmp_path / "subject_s1.hrec")
    assert keys(rec) == [("down", "ball", a, 1) for a in ACTIONS]
    assert rec.meta["subject"] == "s1" and rec.meta["synthetic"] is True
    assert_consistent(rec)


def test_without_quiet_the_session_says_each_step(tmp_path, capsys, monkeypatch):
    from trainer.commands import record_cli

    monkeypatch.setattr(record_cli.shutil, "which", lambda _name: None)  # no voice, whatever is installed
    args = [a for a in SHORT if a != "--quiet"]
    assert handover(["record", "--device", f"subject://?seed=3&speed={SPEED}", "--subject", "s1", "--out",
                     str(tmp_path), *args, "--auto", "--max-trials", "2"]) == 0
    out = capsys.readouterr().out
    assert "Go: pull!" in out and "f1 dist |" in out and "2 of 4 trials done" in out


def on_third_go(subject: ScriptedSubject, act: Callable[[], None]) -> Callable:
    """The subject's cue, with ``act`` run as the third trial's go is given (the trial is being recorded)."""
    gos = 0

    def cue(kind, slot):
        nonlocal gos
        if kind == "go":
            gos += 1
            if gos == 3:
                act()
        return subject.cue(kind, slot)

    return cue


def test_interrupted_session_resumes_where_it_stopped(tmp_path):
    subject = ScriptedSubject(seed=4, speed=SPEED)
    client, store = open_session(tmp_path, subject)

    def ctrl_c() -> None:
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_session(client, store, PLAN, auto_opts(), SessionIO(cue=on_third_go(subject, ctrl_c)))
    client.close()
    partial = Recording.load(store.path)
    assert keys(partial) == [("down", "ball", "pull", 1), ("down", "ball", "push", 1)]

    assert record(tmp_path, "--auto") == 0  # the same command again
    rec = Recording.load(store.path)
    assert sorted(keys(rec)) == sorted(KEYS) and len(rec.trials) == 4
    np.testing.assert_array_equal(rec.trial_frames(rec.trials[0])[0], partial.trial_frames(partial.trials[0])[0])
    assert [t.extra["session"] for t in rec.trials] == [1, 1, 2, 2]
    assert_consistent(rec)


def test_killed_recorder_leaves_a_readable_file_and_resumes(tmp_path):
    import os
    import signal
    import subprocess
    import time

    cmd = [sys.executable, "-m", "runtime.cli", "record", "--device", f"subject://?seed=3&speed={SPEED}",
           "--subject", "s1", "--out", str(tmp_path), *SHORT, "--auto", "--no-look"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    path = tmp_path / "subject_s1.hrec"
    deadline = time.monotonic() + 30
    while not path.exists() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)  # a crash: no handler runs
    proc.wait()
    partial = Recording.load(path)
    assert 1 <= len(partial.trials) <= 4
    assert record(tmp_path, "--auto") == 0
    assert sorted(keys(Recording.load(path))) == sorted(KEYS)


def test_max_trials_then_rerun_completes(tmp_path, capsys):
    assert record(tmp_path, "--auto", "--max-trials", "1") == 0
    assert "1 of 4 trials done" in capsys.readouterr().out
    assert record(tmp_path, "--auto") == 0
    assert "session complete: 4 trials" in capsys.readouterr().out
    assert sorted(keys(Recording.load(tmp_path / "subject_s1.hrec"))) == sorted(KEYS)


def test_resuming_with_another_plan_or_another_simulated_person_is_refused_in_one_line(tmp_path, capsys):
    """--runs changed or another subject://?seed= under the same subject id would mix two protocols or two
    people in one file: refused before anything is recorded, naming the difference; the original command resumes."""
    path = tmp_path / "subject_s1.hrec"
    assert record(tmp_path, "--auto", "--max-trials", "1") == 0
    capsys.readouterr()
    before = path.read_bytes()
    for extra, device, said in ((["--runs", "2"], f"subject://?seed=3&speed={SPEED}", "recorded with --runs 1, not --runs 2"),
                                (["--trial-seconds", "2.5"], f"subject://?seed=3&speed={SPEED}",
                                 "recorded with --trial-seconds 2, not --trial-seconds 2.5"),
                                ([], f"subject://?seed=4&speed={SPEED}", "recorded with subject://?seed=3, not seed=4"),
                                ([], f"subject://?seed=3&lab=B&speed={SPEED}",
                                 "recorded with subject://?seed=3, not seed=3&lab=B")):
        assert record(tmp_path, "--auto", *extra, device=device) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0] == (f"handover record: {path}: {said}: resume with the original options, "
                                            "or record under a new --subject id"), err
        assert path.read_bytes() == before
    assert record(tmp_path, "--auto", device="subject://?seed=3&lab=a&speed=max") == 0  # the playback speed is no plan
    assert sorted(keys(Recording.load(path))) == sorted(KEYS)


def test_redo_and_discard_from_the_prompt(tmp_path, monkeypatch, capsys):
    # trial 1: start, keep; trial 2: start, redo, start, keep; trial 3: start, discard; trial 4: start, keep
    answers = "\n\n" + "\nr\n\n\n" + "\nd\n" + "\n\n"
    monkeypatch.setattr(sys, "stdin", io.StringIO(answers))
    assert record(tmp_path) == 0
    out = capsys.readouterr().out
    assert "r = redo" in out and "3 of 4 trials done" in out
    rec = Recording.load(tmp_path / "subject_s1.hrec")
    assert keys(rec) == [("down", "ball", "pull", 1), ("down", "ball", "push", 1), ("down", "ball", "bump", 1)]
    assert [t.extra["attempt"] for t in rec.trials] == [1, 2, 1]
    # the discarded slot comes back on the next run; end of input answers "quit" cleanly
    monkeypatch.setattr(sys, "stdin", io.StringIO("\n\n"))
    assert record(tmp_path) == 0
    rec = Recording.load(tmp_path / "subject_s1.hrec")
    assert sorted(keys(rec)) == sorted(KEYS)
    assert_consistent(rec)


def test_the_start_prompt_skips_and_quits_trials_and_idle_stretches_in_the_same_words(tmp_path):
    from firmware_io.recordings.idle_session import run_idle
    from firmware_io.recordings.idle_stretches import IdleSlot

    asked: list[str] = []
    answers: list[str] = []

    def ask(question, choices):
        asked.append(question)
        return answers.pop(0)

    subject = ScriptedSubject(seed=3, speed=SPEED)
    client, store = open_session(tmp_path, subject)
    say = SessionIO(ask=ask, cue=subject.cue, sleep=lambda s: None)
    opts = auto_opts(auto=False, countdown=0)
    try:
        answers[:] = ["s", "q"]
        trials = run_session(client, store, PLAN, opts, say)
        answers[:] = ["s", "q"]
        idle = run_idle(client, store, [IdleSlot(0, "quiet", 1.0), IdleSlot(1, "grasp", 1.0)], opts, say)
    finally:
        client.close()
    assert (trials.stopped, trials.done, trials.recorded, store.n_trials) == ("quit", 0, 0, 0)
    assert (idle.stopped, idle.done, idle.recorded) == ("quit", 0, 0)
    assert asked == ["Enter = start, s = skip, q = quit"] * 4
    assert SessionIO().ask_to_start("skipped") is None  # no prompts (auto): the recording starts

def test_never_triggered_trial_is_flagged_and_repeated(tmp_path, capsys):
    subject = ScriptedSubject(seed=3, speed=SPEED, lazy=[1, 3])  # does nothing on the 1st and 3rd go
    client, store = open_session(tmp_path, subject)
    shown: list[str] = []
    result = run_session(client, store, PLAN, auto_opts(retries=1), SessionIO(show=shown.append, cue=subject.cue))
    client.close()
    # without a case_check the paper's level decides
    assert any("training gets no case from this trial (never reached 15% of full scale)" in s for s in shown)
    rec = Recording.load(store.path)
    assert sorted(keys(rec)) == sorted(KEYS)
    assert rec.trials[0].extra["attempt"] == 2 and rec.trials[0].extra["scripted_subject"]["acted"]
    assert sum(t.extra["attempt"] - 1 for t in rec.trials) >= 2  # the two lazy goes were redone
    assert flagged_trials(rec) == result.flagged


def test_never_triggered_trial_kept_flagged_without_retries(tmp_path):
    subject = ScriptedSubject(seed=3, speed=SPEED, lazy=[2])
    client, store = open_session(tmp_path, subject)
    result = run_session(client, store, PLAN, auto_opts(retries=0), SessionIO(cue=subject.cue))
    client.close()
    rec = Recording.load(store.path)
    assert 1 in flagged_trials(rec) and 1 in result.flagged
    lazy = rec.trials[1].extra  # held the placed object (some pressure), never acted
    assert 0 < lazy["peak_fraction"] < lazy["trigger_fraction"] and not lazy["scripted_subject"]["acted"]


def test_with_the_trainers_cut_a_trial_nobody_acted_in_is_flagged_with_its_reason(tmp_path):
    from trainer.dataset import NEVER, case_check

    subject = ScriptedSubject(seed=3, speed=SPEED, lazy=[2])
    client, store = open_session(tmp_path, subject)
    result = run_session(client, store, PLAN, auto_opts(case_check=case_check()), SessionIO(cue=subject.cue))
    client.close()
    rec = Recording.load(store.path)
    assert result.flagged == flagged_trials(rec) == [1], "only the trial nobody acted in"
    assert rec.trials[1].extra["no_case"].startswith(NEVER)
    assert {t.extra["case_cut"] for t in rec.trials} == {str(case_check())} == {"onset trigger, T=15, pads all"}
    assert all(t.extra["no_case"] is None for i, t in enumerate(rec.trials) if i != 1)


def test_the_quick_look_marks_and_stores_the_cut_training_uses_not_the_papers_crossing(tmp_path):
    """The paper's 15 % crossing is not where training cuts (a bump may cross it in the held grasp, before
    the go cue): the recorder marks and stores the onset trigger's frame that ``handover train`` cuts at."""
    from trainer.dataset import case_check

    subject = ScriptedSubject(seed=3, speed=SPEED)
    client, store = open_session(tmp_path, subject)
    shown: list[str] = []
    run_session(client, store, PLAN, auto_opts(case_check=case_check(), quick_look=trial_view),
                SessionIO(show=shown.append, cue=subject.cue))
    client.close()
    rec = Recording.load(store.path)
    assert_consistent(rec)
    marks = [line for s in shown for line in s.splitlines() if line.lstrip().startswith("trigger ")]
    for t, mark in zip(rec.trials, marks, strict=True):
        assert t.extra["trigger_frame"] >= t.extra["go_frame"], (t.action, t.extra["trigger_frame"])
        assert mark.endswith(f"^ frame {t.extra['trigger_frame']}")
    papers = [check_trigger(rec.trial_frames(t)[0], rec.layout).first_frame for t in rec.trials]
    assert papers != [t.extra["trigger_frame"] for t in rec.trials], "the two cuts must differ for this to test"


def test_link_drop_mid_trial_reconnects_and_records_the_trial_again(tmp_path):
    subject = ScriptedSubject(seed=3, speed=SPEED)
    client, store = open_session(tmp_path, subject)

    def drop_soon() -> None:
        subject.drop_at = {subject.emitted + 20}  # the link drops 20 frames into trial 3

    shown: list[str] = []
    result = run_session(client, store, PLAN, auto_opts(), SessionIO(show=shown.append, cue=on_third_go(subject, drop_soon)))
    assert client.stats["reconnects"] == 1 and subject.connections == 2
    client.close()
    assert result.complete
    assert any("reconnected during this trial" in s for s in shown)
    assert len(subject.performed) == 5
    rec = Recording.load(store.path)
    assert keys(rec) == [("down", "ball", a, 1) for a in ACTIONS]
    assert_consistent(rec)


def test_unplugged_device_saves_exits_with_one_line_and_resumes(tmp_path, capsys):
    # 10x real time: the unplug after 200 frames comes once a trial is saved (at SPEED it can come before any)
    code = record(tmp_path, "--auto", device="subject://?seed=3&speed=10&unplug=200")
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1
    assert err[0].startswith("handover record: device lost") and "run the same command again" in err[0]
    partial = Recording.load(tmp_path / "subject_s1.hrec")
    assert 1 <= len(partial.trials) < 4
    assert record(tmp_path, "--auto") == 0
    rec = Recording.load(tmp_path / "subject_s1.hrec")
    assert sorted(keys(rec)) == sorted(KEYS)
    assert_consistent(rec)


def test_a_full_disk_says_what_was_saved_and_running_again_resumes(tmp_path, capsys, monkeypatch):
    """ENOSPC while saving the third trial (injected in the zip writer, half the member written) was two
    chained OSError tracebacks; now one line says the trial in progress is lost, which trials the file
    holds and to run again, no temporary file stays, and once space returns the same command completes."""
    import errno
    import zipfile

    real, saves = zipfile.ZipFile.writestr, []

    def writestr(self, info, data, *a, **kw):
        if getattr(info, "filename", info) == "header.json":
            saves.append(1)
        if len(saves) > 2 and getattr(info, "filename", info) == "frames.npy":
            real(self, info, data[: len(data) // 2], *a, **kw)
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, info, data, *a, **kw)

    monkeypatch.setattr(zipfile.ZipFile, "writestr", writestr)
    assert record(tmp_path, "--auto", "--no-look") == 2
    err = capsys.readouterr().err.strip().splitlines()
    path = tmp_path / "subject_s1.hrec"
    assert len(err) == 1 and err[0] == (f"handover record: the recording just made could not be saved and is lost (No "
                                        f"space left on device); 2 trials saved in {path}; free disk space, then run "
                                        "the same command again to resume"), err
    assert len(Recording.load(path).trials) == 2 and sorted(p.name for p in tmp_path.iterdir()) == [path.name]
    monkeypatch.setattr(zipfile.ZipFile, "writestr", real)  # space again
    assert record(tmp_path, "--auto", "--no-look") == 0
    assert sorted(keys(Recording.load(path))) == sorted(KEYS)


def test_a_full_disk_before_the_first_save_says_nothing_was_saved(tmp_path, capsys, monkeypatch):
    """It said "0 trials saved in .../subject_s1.hrec", a file that does not exist."""
    import errno
    import zipfile

    def writestr(self, info, data, *a, **kw):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(zipfile.ZipFile, "writestr", writestr)
    assert record(tmp_path, "--auto", "--no-look") == 2
    err = capsys.readouterr().err.strip().splitlines()
    path = tmp_path / "subject_s1.hrec"
    assert len(err) == 1 and f"; nothing saved yet ({path} was not written); free disk space, then run" in err[0], err
    assert not path.exists()


def test_resuming_removes_the_temporary_files_a_killed_save_left_and_nothing_else(tmp_path):
    """kill -9 during a save left ``.subject_s1.hrec.XXXXXXXX.tmp`` for ever: the resumed session removes
    save's own pattern for its file, and keeps every other name, a symlink and another subject's temp."""
    assert record(tmp_path, "--auto", "--no-look", "--max-trials", "1") == 0
    stale = tmp_path / ".subject_s1.hrec.k2_9xq0a.tmp"
    stale.write_bytes(b"PK half a recording")
    kept = [tmp_path / n for n in (".subject_s2.hrec.k2_9xq0a.tmp", ".subject_s1.hrec.short.tmp", "notes.tmp",
                                   ".subject_s1.hrec.k2_9xq0a.tmp.keep")]
    for p in kept:
        p.write_text("not ours")
    outside = tmp_path.parent / f"{tmp_path.name}-target"
    outside.write_text("someone else's")
    link = tmp_path / ".subject_s1.hrec.abcdefgh.tmp"
    link.symlink_to(outside)
    assert record(tmp_path, "--auto", "--no-look") == 0
    assert not stale.exists() and all(p.exists() for p in kept) and link.is_symlink() and outside.exists()


def test_session_over_tcp(tmp_path):
    from firmware_io.emulator.server import TcpEmulatorServer

    subject = ScriptedSubject(seed=5, speed=SPEED)
    with TcpEmulatorServer(subject.emulator) as server:
        client = DSAClient(server.url)
        layout = client.open()
        client.start()
        store = SessionStore.open(recording_path(tmp_path, "s2"), "s2", layout)
        result = run_session(client, store, PLAN, auto_opts(), SessionIO(cue=subject.cue))
        client.close()
    assert result.complete
    rec = Recording.load(store.path)
    assert sorted(keys(rec)) == sorted(KEYS)
    assert_consistent(rec)


# -- files the trainer takes ---------------------------------------------------------------------
def _two_subjects(tmp_path, runs: int) -> None:
    for i, name in enumerate(("s1", "s2")):
        extra = ["--auto", "--runs", str(runs), "--no-look"]
        assert record(tmp_path, *extra, device=f"subject://?seed={10 + i}&speed={SPEED}", subject=name) == 0


def test_recorded_files_assemble_into_a_dataset(tmp_path):
    from firmware_io.recordings.recording import find_recordings, load_all
    from trainer.dataset import build_dataset

    _two_subjects(tmp_path, runs=1)
    recs = load_all(find_recordings(tmp_path))
    ds = build_dataset(recs)
    assert ds.n_trials == 8 and set(ds.groups) <= {"s1", "s2"}
    # handover record checks each trial with the trainer's own cut: its flags are what training drops, and why
    no_case = [t.extra["no_case"] for r in recs for t in r.trials if t.extra["no_case"] is not None]
    assert len(ds.y) == ds.n_trials - len(no_case) and sorted(no_case) == sorted(s.reason for s in ds.untriggered)
    assert sum(len(flagged_trials(r)) for r in recs) == len(no_case)
    assert ds.X.shape[1:] == (486, 15)
    assert 25 < ds.sample_rate_hz < 40


@pytest.mark.slow
def test_recorded_files_train_a_model(tmp_path):
    _two_subjects(tmp_path / "data", runs=3)
    code = handover(["train", "--data", str(tmp_path / "data"), "--out", str(tmp_path / "report"),
                     "--no-sweep", "--no-onnx", "--repeats", "2", "--quiet"])
    assert code == 0


# -- errors and plots ------------------------------------------------------------------------------
def test_bad_inputs_give_one_line(tmp_path, capsys):
    assert record(tmp_path, "--auto", device="nosuch://x") != 0
    assert record(tmp_path, "--auto", "--runs", "0") != 0
    with pytest.raises(SystemExit):  # argparse's type refuses it as it is read
        record(tmp_path, "--auto", "--fraction", "1.5")
    (tmp_path / "subject_s1.hrec").write_bytes(b"not a zip")
    assert record(tmp_path, "--auto") != 0
    for line in [x for x in capsys.readouterr().err.splitlines() if x]:
        assert line.startswith("handover record: ")


def test_file_of_another_subject_is_refused(tmp_path, capsys):
    assert record(tmp_path, "--auto", "--max-trials", "1") == 0
    (tmp_path / "subject_s1.hrec").rename(tmp_path / "subject_s9.hrec")
    assert record(tmp_path, "--auto", subject="s9") == 2
    assert "belongs to subject 's1'" in capsys.readouterr().err


@pytest.mark.parametrize(("flag", "value", "words"), [("--runs", "100000000", "runs must be from 1 to 100, got 100000000"),
                                                    ("--max-trials", "0", "--max-trials must be at least 1, got 0"),
                                                    ("--max-trials", "-1", "--max-trials must be at least 1, got -1")])
def test_counts_that_plan_forever_or_nothing_are_one_line(tmp_path, capsys, flag, value, words):
    """--runs 100000000 never started (the plan is listed first); --max-trials 0 or -1 recorded nothing and
    said '0 trials saved in' a file it never wrote."""
    assert record(tmp_path / "out", "--auto", flag, value, device="subject://?seed=3&speed=max") == 2
    err = [x for x in capsys.readouterr().err.splitlines() if x]
    assert err == [f"handover record: {words}"] and not (tmp_path / "out").exists()


@pytest.mark.parametrize(("flag", "value"), [("--trial-seconds", "nan"), ("--trial-seconds", "inf"), ("--lead-in", "nan"),
                                           ("--lead-in", "inf"), ("--gap", "nan"), ("--gap", "1e9")])
def test_spans_that_are_not_a_number_of_seconds_are_one_line(tmp_path, capsys, flag, value):
    """--lead-in nan or inf hung the first trial; --trial-seconds inf ended in an OverflowError traceback,
    nan in 'cannot convert float NaN to integer'; --gap nan in 'Invalid value NaN'."""
    assert record(tmp_path, "--auto", flag, value, device="subject://?seed=3&speed=max") == 2
    err = [x for x in capsys.readouterr().err.splitlines() if x]
    assert len(err) == 1 and err[0].startswith(f"handover record: {flag}: ") and err[0].endswith(f"got {float(value)}")


@pytest.mark.parametrize("subject", ["y" * 300, "s1\n", "../s1", "s\x1b[31m"])
def test_a_subject_id_that_cannot_name_the_file_is_one_line_before_the_device_opens(tmp_path, capsys, subject):
    """300 characters ended in an OSError traceback (file name too long) after the device had opened;
    a trailing newline passed the name check ($ matches before it) and named the file with it."""
    device = "subject://?seed=3&speed=max"
    assert record(tmp_path / "out", "--auto", device=device, subject=subject) == 2
    err = [x for x in capsys.readouterr().err.splitlines() if x]
    assert len(err) == 1 and err[0].startswith("handover record: subject id ")
    assert not (tmp_path / "out").exists()
    code = handover(["import", str(tmp_path / "none.dsa"), "--out", str(tmp_path / "o"), "--idle", "quiet",
                     "--subject", subject])
    err = [x for x in capsys.readouterr().err.splitlines() if x]
    assert code == 2 and len(err) == 1 and err[0].startswith("handover import: --subject: subject id ")


def test_plot_writes_a_figure_and_lists_trials(tmp_path, capsys):
    assert record(tmp_path, "--auto", "--max-trials", "2", "--no-look") == 0
    path = tmp_path / "subject_s1.hrec"
    assert handover(["plot", str(path), "--list"]) == 0
    assert "push run 1" in capsys.readouterr().out
    png = tmp_path / "t.png"
    assert handover(["plot", str(path), "--trial", "2", "--out", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert handover(["plot", str(path), "--trial", "9"]) == 2
    assert handover(["plot", str(tmp_path / "missing.hrec")]) == 2


def test_the_session_line_names_the_flagged_trials_and_how_to_look_at_one():
    from trainer.commands.record_cli import _flagged_text

    assert _flagged_text([], "s1.hrec") == ""
    said = _flagged_text([6, 9], "data/s1.hrec")
    assert said == (", 2 flagged (trials 7, 10): training gets no case from them; look at one with "
                    "`handover plot data/s1.hrec --trial 7`")
    assert "(trials 1, 2, 3, 4, 5 ...)" in _flagged_text(list(range(8)), "x.hrec")
    assert _flagged_text([6], "s1.hrec") == (", 1 flagged (trial 7): training gets no case from it; look at it with "
                                             "`handover plot s1.hrec --trial 7`")


def test_what_was_saved_is_counted_in_words(tmp_path):
    """A session killed after one trial said "1 trials saved"."""
    from types import SimpleNamespace

    from trainer.commands.record_cli import _saved

    path = tmp_path / "subject_s1.hrec"
    path.write_bytes(b"x")
    one = SimpleNamespace(path=path, n_trials=1, n_idle=1, idle_seconds=lambda: 81.0)
    assert _saved(one) == f"1 trial and 1 idle stretch (1.4 min) saved in {path}"
    two = SimpleNamespace(path=path, n_trials=2, n_idle=0, idle_seconds=lambda: 0.0)
    assert _saved(two) == f"2 trials saved in {path}"
