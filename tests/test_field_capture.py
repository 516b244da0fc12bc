"""Field capture (#39): every decided window kept as a recording, idle sampled, the robot's outcome attached.

A daemon on the simulated hand with ``[capture] folder``; the writer's folder rules (max_mb, a folder that
refuses files, another user's folder, kill -9 mid-write) on the writer itself; the idle sample on the
listener with a stand-in detector (device time injected through the frames' stamps, no wall clock).
"""

from __future__ import annotations

import errno
import json
import logging
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from firmware_io.layout import SensorLayout
from firmware_io.recordings.field_capture import EVENT_FIELDS, META_KEY, OUTCOME_WORDS, OUTCOMES_FILE
from firmware_io.recordings.recording import Recording, find_recordings
from runtime.capture import IDLE_S, POST_FRAMES, PRE_FRAMES, FieldCapture
from runtime.capture_writer import Capture, CaptureError, CaptureWriter, Outcome
from runtime.config import config_from_dict
from runtime.daemon import Daemon
from runtime.listeners import FrameListener
from runtime.sinks import Event
from tests.tiny_models import tiny_model_bytes, write_model
from tests.waiting import wait_for

pytest.importorskip("onnx")
ROOT = Path(__file__).resolve().parents[1]
N_EVENTS = 6
TRIGGER = {"fraction": 0.02, "hysteresis": 0.01, "refractory_s": 1.0}
"""The simulated hand presses lightly (synthetic): a low threshold makes every scripted event trigger."""


def _daemon(tmp_path: Path, on_event=None, url: str = f"sim://?events={N_EVENTS}&realtime=0&loop=0", **extra) -> Daemon:
    models = tmp_path / "models"
    models.mkdir(exist_ok=True)
    write_model(models, "m.onnx", tiny_model_bytes(), mtime=time.time() - 100)
    data = {"device": {"url": url, "reconnect_min_s": 0.05},
            "model": {"folder": str(models), "poll_interval_s": 0.05}, "sinks": {"stdout": False}, "trigger": TRIGGER,
            "capture": {"folder": str(tmp_path / "field")}}
    for key, value in extra.items():
        data.setdefault(key, {}).update(value) if isinstance(value, dict) else data.update({key: value})
    return Daemon(config_from_dict(data), on_event=on_event)


def _serve(daemon: Daemon, timeout: float = 60.0) -> None:
    """Run until the scripted session ends (the device's end of stream)."""
    def watch():
        wait_for(lambda: daemon.health.device_faults >= 1, timeout)
        daemon.request_stop()

    threading.Thread(target=watch, daemon=True).start()
    daemon.run()


def _events(folder: Path) -> dict[int, Recording]:
    return {(rec := Recording.load(p)).meta[META_KEY]["frame_last"]: rec for p in find_recordings(folder)
            if p.name.startswith("event-")}


def test_every_event_line_has_its_captured_window(tmp_path):
    from firmware_io.emulator.device import DeviceEmulator
    from firmware_io.emulator.frame_source import load_source
    from firmware_io.emulator.server import TcpEmulatorServer

    server = TcpEmulatorServer(DeviceEmulator(load_source("sim", seed=0, events=N_EVENTS), speed=None, loop=False))
    events: list[Event] = []
    daemon = _daemon(tmp_path, events.append, url=server.start().url)
    try:
        _serve(daemon)
    finally:
        server.stop()
    captured = _events(tmp_path / "field")
    assert len(events) == N_EVENTS and sorted(captured) == [e.frame_last for e in events]
    for event in events:
        rec = captured[event.frame_last]
        meta = rec.meta[META_KEY]
        assert tuple(meta) == EVENT_FIELDS and meta["kind"] == "event"
        assert meta["class"] == event.cls == rec.trials[0].action and meta["model_id"] == event.model_id
        assert meta["frame_first"] == event.frame_first and meta["scores"] == pytest.approx(event.scores, abs=1e-5)
        report = meta["report_frame"]
        assert report == PRE_FRAMES + event.frame_last - event.frame_first  # no frame lost on the way
        assert rec.n_frames == report + POST_FRAMES + 1 and rec.trials[0].first == 0
        assert rec.trials[0].last == rec.n_frames - 1
    h = daemon.health.snapshot()
    assert h["capture_events"] == N_EVENTS and h["capture_dropped"] == h["capture_errors"] == 0
    assert h["capture_bytes"] == sum(p.stat().st_size for p in (tmp_path / "field").iterdir())


def test_train_reads_the_events_a_person_confirmed(tmp_path):
    """The captured idle's side: test_idle_is_sampled_by_device_time_and_read_by_train_as_its_source (the
    simulated session has no 10 s without an event)."""
    from firmware_io.recordings.field_capture import LABELS_FILE
    from trainer.field_folder import field_recordings

    daemon = _daemon(tmp_path, instance="robot1")
    _serve(daemon)
    folder = tmp_path / "field"
    stems = sorted(p.stem for p in find_recordings(folder) if p.name.startswith("event-"))
    (folder / LABELS_FILE).write_text(json.dumps({stems[0]: "pull", stems[1]: "push"}))  # as review writes it
    lines: list[str] = []
    recs, _names = field_recordings(folder, lines.append)
    trials = [t for r in recs for t in r.trials]
    assert [t.action for t in trials] == ["pull", "push"] and {t.subject for t in trials} == {"field-robot1"}
    assert any(f"{N_EVENTS - 2} of {N_EVENTS} captured events have no confirmed label" in line for line in lines)


def test_windows_decided_but_not_reported_are_kept_as_such(tmp_path):
    daemon = _daemon(tmp_path, scene={"events": ["push"]})  # the tiny model decides pull: never reported
    _serve(daemon)
    captured = _events(tmp_path / "field")
    assert daemon.reporter.events == 0 and len(captured) == daemon.reporter.decisions == N_EVENTS
    assert {r.meta[META_KEY]["kind"] for r in captured.values()} == {"unreported"}
    assert daemon.capture.last_event is None  # an outcome has no event to attach to


class _Robot(FrameListener):
    """Says outcomes on the control socket from the hot thread and waits until the daemon has handled each, so
    what each is attached to is fixed: one before any event, then two after the first event."""

    def __init__(self, daemon: Daemon, address: str) -> None:
        self.daemon, self.address, self.first_event = daemon, address, None
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)

    def _say(self, text: str) -> None:
        capture = self.daemon.capture
        before = capture.refused + capture.writer.outcomes
        self.sock.sendto(text.encode(), self.address)
        assert wait_for(lambda: capture.refused + capture.writer.outcomes > before, 5.0), text

    def on_frame(self, frame) -> None:
        if frame.number == 0:
            self._say("outcome kept")

    def on_decision(self, decision) -> None:
        if self.first_event is None and decision.report >= 0:
            self.first_event = decision.frame.number
            self._say("outcome taken")
            self._say("outcome bogus")


def test_an_outcome_lands_against_the_right_event_and_bad_ones_get_one_line_each(tmp_path, caplog):
    address = str(tmp_path / "control.sock")
    daemon = _daemon(tmp_path, control={"socket": address})
    daemon.start_control()
    daemon.start_capture()
    robot = _Robot(daemon, address)
    daemon.listeners.append(robot)
    with caplog.at_level(logging.WARNING, "handover"):
        _serve(daemon)
    lines = (tmp_path / "field" / OUTCOMES_FILE).read_text().splitlines()
    assert len(lines) == 1
    line = json.loads(lines[0])
    assert line["outcome"] == "taken" and line["source"] == "control"
    rec = Recording.load(tmp_path / "field" / f"{line['event']}.hrec")
    assert rec.meta[META_KEY]["frame_last"] == robot.first_event
    said = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING and "outcome" in r.getMessage()]
    assert len(said) == 2 and "no event captured yet" in said[0] and "unknown outcome 'bogus'" in said[1], said
    h = daemon.health.snapshot()
    assert h["capture_outcomes"] == 1 and h["capture_outcomes_refused"] == 2 and daemon.reporter.events == N_EVENTS


def test_a_folder_that_refuses_files_costs_one_line_and_no_event(tmp_path, caplog, monkeypatch):
    """A full or read-only disk (injected: the daemon runs as root here, for whom chmod changes nothing)."""
    import firmware_io.recordings.recording as recording

    def refuse(*_a, **_k):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS))

    monkeypatch.setattr(recording.tempfile, "mkstemp", refuse)
    events: list[Event] = []
    daemon = _daemon(tmp_path, events.append)
    with caplog.at_level(logging.WARNING, "handover.capture"):
        _serve(daemon)
    assert len(events) == N_EVENTS  # the sinks got every event
    said = [r.getMessage() for r in caplog.records if r.name == "handover.capture" and r.levelno >= logging.WARNING]
    assert len(said) == 1 and "Read-only file system" in said[0], said
    h = daemon.health.snapshot()
    assert h["capture_errors"] == N_EVENTS and h["capture_events"] == 0 and "capture folder" in h["last_error"]


def _capture(stem: str, n: int = 80, t0: float = 0.0) -> Capture:
    layout = SensorLayout.sdh2()
    frames = np.full((n, layout.n_taxels), 7, np.uint16)
    return Capture(stem, frames, t0 + np.arange(n) / 32.0, layout, {"subject": "field"},
                   trial={"subject": "field", "object": "-", "pose": "-", "action": "pull", "run": 0})


def _written(writer: CaptureWriter, n: int) -> None:
    assert wait_for(lambda: writer.events + writer.idle + writer.errors + writer.outcomes >= n, 10.0)


def test_max_mb_holds_the_oldest_going_first(tmp_path):
    folder = tmp_path / "field"
    writer = CaptureWriter(folder, max_mb=1.0).start()
    try:
        for k in range(30):  # 30 x 78 kB: more than 1 MB
            writer.put(_capture(f"event-{k:09d}-{1000 + k:013d}"))
            _written(writer, k + 1)
            assert sum(p.stat().st_size for p in folder.iterdir()) <= 1e6
    finally:
        writer.stop()
    names = sorted(p.name for p in find_recordings(folder))
    assert names[-1].startswith("event-000000029-") and not any(n.startswith("event-000000000-") for n in names)
    assert writer.removed == 30 - len(names) > 0 and writer.bytes == sum(p.stat().st_size for p in folder.iterdir())


def test_outcomes_of_removed_events_are_dropped_so_outcomes_jsonl_never_fills_the_folder(tmp_path):
    """Outcome lines outlive their events; once outcomes.jsonl held max_mb no capture fitted again."""
    from runtime.capture_writer import OUTCOMES_SHARE

    folder = tmp_path / "field"
    writer = CaptureWriter(folder, max_mb=1.0).start()
    try:
        for k in range(150):  # 150 events of 4 outcomes: 66 kB of lines, over 5 % of 1 MB
            stem = f"event-{k:09d}-{1000 + k:013d}"
            writer.put(_capture(stem, n=8))
            for word in ("taken", "kept", "dropped", "pull"):
                writer.put(Outcome({"event": stem, "outcome": word, "source": "control", "time": 1.0}))
            _written(writer, 5 * (k + 1))
    finally:
        writer.stop()
    lines = [json.loads(line) for line in (folder / OUTCOMES_FILE).read_text().splitlines()]
    assert (folder / OUTCOMES_FILE).stat().st_size <= OUTCOMES_SHARE * 1e6 and writer.errors == 0
    assert lines[-1]["event"] == stem and writer.outcomes == 600 and len(lines) < 600
    assert not (folder / "event-000000000-0000000001000.hrec").exists()
    assert lines[0]["event"] != "event-000000000-0000000001000" and writer.removed > 0  # its lines went with it


def test_the_writer_keeps_trying_and_says_when_it_works_again(tmp_path, caplog, monkeypatch):
    import firmware_io.recordings.recording as recording

    real = recording.tempfile.mkstemp
    full = [True]

    def maybe(*a, **k):
        if full[0]:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(*a, **k)

    monkeypatch.setattr(recording.tempfile, "mkstemp", maybe)
    writer = CaptureWriter(tmp_path / "field", max_mb=10).start()
    with caplog.at_level(logging.INFO, "handover.capture"):
        for k in range(3):
            writer.put(_capture(f"event-{k:09d}-{k:013d}"))
        _written(writer, 3)
        assert writer.problem and "No space left" in writer.problem
        full[0] = False
        writer.put(_capture("event-000000009-0000000000009"))
        _written(writer, 4)
        writer.stop()
    said = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(said) == 2 and "No space left" in said[0] and "takes files again" in said[1], said
    assert writer.errors == 3 and writer.events == 1 and writer.problem is None


def test_a_vanished_folder_is_not_made_again_and_is_used_when_it_is_back(tmp_path, caplog):
    folder = tmp_path / "field"
    writer = CaptureWriter(folder, max_mb=10).start()
    with caplog.at_level(logging.INFO, "handover.capture"):
        writer.put(_capture("event-000000001-0000000000001"))
        _written(writer, 1)
        for p in folder.iterdir():
            p.unlink()
        folder.rmdir()  # removed, or its disk unmounted
        for k in range(2, 5):
            writer.put(_capture(f"event-{k:09d}-{k:013d}"))
        _written(writer, 4)
        assert not folder.exists() and writer.errors == 3 and "gone" in writer.problem
        folder.mkdir()
        writer.put(_capture("event-000000009-0000000000009"))
        _written(writer, 5)
        writer.stop()
    said = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(said) == 2 and "gone" in said[0] and "takes files again" in said[1], said
    assert [p.name for p in folder.iterdir()] == ["event-000000009-0000000000009.hrec"]
    assert writer.bytes == (folder / "event-000000009-0000000000009.hrec").stat().st_size


def test_a_full_queue_drops_and_never_blocks(tmp_path):
    writer = CaptureWriter(tmp_path / "field", max_mb=10)  # not started: nothing takes from the queue
    taken = [writer.put(Outcome({"n": k})) for k in range(40)]
    assert taken.count(True) == 16 and writer.dropped == 24


@pytest.mark.parametrize("mode, owner", [(0o777, None), (0o755, 4321), (0o1777, None)])
def test_a_folder_another_user_may_write_is_refused(tmp_path, mode, owner):
    folder = tmp_path / "field"
    folder.mkdir()
    folder.chmod(mode)
    if owner is not None:
        if os.geteuid() != 0:
            pytest.skip("giving a folder to another user needs root")
        os.chown(folder, owner, -1)
    with pytest.raises(CaptureError, match=r"capture\.folder .*(writable by others|owned by uid 4321)"):
        CaptureWriter(folder, 10).start()
    config = tmp_path / "h.toml"
    (tmp_path / "models").mkdir()
    config.write_text(f'[device]\nurl = "sim://"\n[model]\nfolder = "{tmp_path / "models"}"\n'
                      f'[capture]\nfolder = "{folder}"\n')
    run = subprocess.run([sys.executable, "-m", "runtime.cli", "run", "--config", str(config), "--check"], cwd=ROOT,
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and run.stderr.count("\n") == 1 and "capture.folder" in run.stderr, run.stderr


def test_a_capture_folder_that_is_a_model_folder_or_a_symlink_loop_is_one_line(tmp_path):
    """Through a symlink or ``..`` too; a loop once raised RuntimeError from Path.resolve (a traceback)."""
    from runtime.config import ConfigError

    models, shadow = tmp_path / "models", tmp_path / "shadow"
    models.mkdir(), shadow.mkdir()
    (tmp_path / "link").symlink_to(models)
    for capture, key in ((tmp_path / "link", "model.folder"), (models / ".." / "shadow", "model.shadow")):
        with pytest.raises(ConfigError, match=rf"^capture.folder: .* is {key}: recordings would mix with the models"):
            config_from_dict({"model": {"folder": str(models), "shadow": str(shadow)}, "capture": {"folder": str(capture)}})
    (tmp_path / "a").symlink_to(tmp_path / "b")
    (tmp_path / "b").symlink_to(tmp_path / "a")
    config_from_dict({"model": {"folder": str(models), "shadow": str(tmp_path / "a")}, "capture": {"folder": str(tmp_path / "b")}})
    with pytest.raises(CaptureError, match="is not a folder"):
        CaptureWriter(tmp_path / "b", 10).start()


KILLED_MID_WRITE = """
import os, sys, time
import numpy as np
from runtime.capture_writer import Capture, CaptureWriter
from firmware_io.layout import SensorLayout
real = os.fsync
def stuck(fd):
    print("writing", flush=True)
    time.sleep(60)
os.fsync = stuck
layout = SensorLayout.sdh2()
w = CaptureWriter(sys.argv[1], 10).start()
w.put(Capture("event-000000001-0000000000001", np.zeros((80, layout.n_taxels), np.uint16), np.arange(80) / 32.0,
              layout, {}, trial={"subject": "field", "object": "-", "pose": "-", "action": "pull", "run": 0}))
time.sleep(60)
"""


def test_kill_9_mid_write_leaves_nothing_train_reads_and_the_next_start_cleans_up(tmp_path):
    folder = tmp_path / "field"
    child = subprocess.Popen([sys.executable, "-c", KILLED_MID_WRITE, str(folder)], cwd=ROOT, stdout=subprocess.PIPE,
                             text=True)
    try:
        assert child.stdout.readline() == "writing\n"  # the file's bytes are out, not yet fsynced nor renamed
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait(10)
    left = [p.name for p in folder.iterdir()]
    assert len(left) == 1 and left[0].startswith(".event-000000001-") and left[0].endswith(".tmp")
    assert find_recordings(folder) == []  # handover train reads *.hrec only, never a dot-temp name
    CaptureWriter(folder, 10).start().stop()
    assert list(folder.iterdir()) == []


class _Detector(SimpleNamespace):
    """What FieldCapture reads of the detector, set by hand."""


def _stand_in() -> _Detector:
    return _Detector(arm=SimpleNamespace(moving=False), grasp_closed=True, window_open=False,
                     layout=SensorLayout.sdh2(), windows=SimpleNamespace(every_frame=False), model=None)


def _frames(capture: FieldCapture, det: _Detector, first: int, n: int) -> None:
    for k in range(first, first + n):
        capture.on_frame(SimpleNamespace(number=k, timestamp_ms=31.25 * k,
                                         values=np.full(det.layout.n_taxels, k % 4096, np.uint16)))


def test_idle_is_sampled_by_device_time_and_read_by_train_as_its_source(tmp_path):
    from trainer.recorded_idle import idle_pieces

    writer = CaptureWriter(tmp_path / "field", 10).start()
    det = _stand_in()
    capture = FieldCapture(writer, det, "test", idle_every_s=30.0)
    stretch = int(IDLE_S * 32)
    _frames(capture, det, 0, 35 * 32)  # 35 s of a still grasp: one stretch (at 10 s), the next not before 40 s
    det.arm.moving = True  # the arm moves from 35 s on: a new run, its stretch at 45 s
    _frames(capture, det, 35 * 32, stretch + 10)
    _frames(capture, det, 0, stretch + 1)  # the device restarted (its time from 0): sampled again, not in 40 s
    writer.stop()
    recs = [Recording.load(p) for p in find_recordings(tmp_path / "field")]
    stretches = [r.meta["idle_stretches"][0] for r in recs]
    assert sorted((s["source"], s["frame_first"] >= 35 * 32) for s in stretches) == [
        ("arm_move", False), ("arm_move", True), ("quiet", False)]  # the first arm stretch all of the arm's time
    for rec in recs:
        assert rec.trials == [] and abs(rec.n_frames - stretch) <= 1
        assert [(a, b) for a, b, _ in idle_pieces(rec)] == [(0, rec.n_frames - 1)]
    from trainer.field_folder import field_recordings

    read, _names = field_recordings(tmp_path / "field", lambda _line: None)  # train --data on the folder
    assert [r.meta["subject"] for r in read] == ["field-test"] * 3 and all(idle_pieces(r) for r in read)
    assert writer.idle == 3


@pytest.mark.parametrize("word", [*OUTCOME_WORDS, "push"])
def test_each_outcome_word_is_heard_on_the_control_socket_and_kept(tmp_path, word):
    from runtime.control import parse_message

    assert parse_message(f"  Outcome {word.upper()}\n".encode()) == ("outcome", word)
    writer = CaptureWriter(tmp_path / "field", 10)
    det = _stand_in()
    det.model = SimpleNamespace(meta=SimpleNamespace(classes=("pull", "push", "hold", "bump")))
    capture = FieldCapture(writer, det)
    capture.last_event = "event-000000193-0000000000001"
    assert capture.outcome(word, "control") and capture.refused == 0


def test_a_robot_repeating_its_outcome_keeps_a_few_per_event_and_never_evicts_the_events(tmp_path, caplog):
    """A robot saying ``outcome taken`` in a loop once filled max_mb with outcomes.jsonl and removed every event."""
    from runtime.capture import OUTCOMES_PER_EVENT

    writer = CaptureWriter(tmp_path / "field", 10).start()
    det = _stand_in()
    det.model = SimpleNamespace(meta=SimpleNamespace(classes=("pull", "push", "hold", "bump")))
    capture = FieldCapture(writer, det)
    with caplog.at_level(logging.WARNING, "handover.capture"):
        for stem in ("event-000000193-0000000000001", "event-000000400-0000000000002"):
            capture.last_event = stem
            kept = [capture.outcome("taken", "control") for _ in range(1000)]
            assert kept.count(True) == OUTCOMES_PER_EVENT
    writer.stop()
    assert capture.refused == 2 * (1000 - OUTCOMES_PER_EVENT) and writer.outcomes == 2 * OUTCOMES_PER_EVENT
    assert len((tmp_path / "field" / OUTCOMES_FILE).read_text().splitlines()) == 2 * OUTCOMES_PER_EVENT
    assert len([r for r in caplog.records if "say one per event" in r.getMessage()]) == 1


def test_a_reload_moves_capture_to_another_folder_and_refuses_an_unsafe_one(tmp_path, caplog):
    from runtime.config import load_config

    (tmp_path / "models").mkdir()
    config = tmp_path / "h.toml"

    def write(folder: Path | None) -> None:
        capture = f'[capture]\nfolder = "{folder}"\n' if folder else ""
        config.write_text(f'[device]\nurl = "sim://"\n[model]\nfolder = "{tmp_path / "models"}"\n[sinks]\nstdout = false\n'
                          + capture)

    write(tmp_path / "a")
    daemon = Daemon(load_config(config))
    daemon.start_capture()
    first = daemon.capture
    assert first.writer.folder == tmp_path / "a" and daemon.listeners == [first]
    write(tmp_path / "b")
    daemon.reload()
    assert daemon.capture is not first and daemon.capture.writer.folder == tmp_path / "b"
    assert daemon.listeners == [daemon.capture] and daemon.robot.capture is daemon.capture
    assert first.writer._thread is None  # the old writer wrote what it held and ended
    unsafe = tmp_path / "c"
    unsafe.mkdir(mode=0o777)
    unsafe.chmod(0o777)
    write(unsafe)
    with caplog.at_level(logging.ERROR, "handover.daemon"):
        daemon.reload()
    kept = daemon.capture
    assert kept.writer.folder == tmp_path / "b" and "writable by others" in caplog.text
    write(None)
    daemon.reload()
    assert daemon.capture is None and daemon.listeners == [] and kept.writer._thread is None


def test_a_failure_inside_capture_never_costs_a_decision(tmp_path, caplog):
    events: list[Event] = []
    daemon = _daemon(tmp_path, events.append)
    daemon.start_capture()
    daemon.capture._rows = None  # a bug of capture's own: every window's copy fails
    with caplog.at_level(logging.ERROR, "handover.capture"):
        _serve(daemon)
    assert len(events) == N_EVENTS and daemon.health.frame_errors == 0
    assert daemon.health.capture_errors == N_EVENTS and daemon.health.capture_events == 0
    assert len([r for r in caplog.records if r.name == "handover.capture" and r.levelno >= logging.ERROR]) == 1


def test_check_warns_in_one_line_when_the_capture_folder_cannot_be_written(tmp_path, monkeypatch, capsys):
    """A read-only file system or another user's folder (root writes anywhere: os.access injected)."""
    from runtime.cli import main as handover

    (tmp_path / "models").mkdir()
    write_model(tmp_path / "models", "m.onnx", tiny_model_bytes(), mtime=time.time() - 100)
    config = tmp_path / "h.toml"
    config.write_text(f'[device]\nurl = "sim://"\n[model]\nfolder = "{tmp_path / "models"}"\n'
                      f'[capture]\nfolder = "{tmp_path / "field" / "new"}"\n')
    assert handover(["run", "--config", str(config), "--check"]) == 0
    assert "capture" not in capsys.readouterr().err
    real = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: False if Path(p) == tmp_path else real(p, mode))
    assert handover(["run", "--config", str(config), "--check"]) == 0
    lines = [line for line in capsys.readouterr().err.splitlines() if "capture.folder" in line]
    assert len(lines) == 1 and f"{tmp_path} is not writable by this user; captures would be lost" in lines[0]
