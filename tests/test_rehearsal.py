"""The rehearsal (runtime.rehearsal): the model runs once shortly before a due frame, in a thread,
and never changes a decision."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time

import numpy as np

import runtime.rehearsal as rehearsal_module
from firmware_io.client import Frame
from firmware_io.layout import SensorLayout
from runtime.config import config_from_dict
from runtime.daemon import Daemon
from runtime.model import load_model
from runtime.rehearsal import REHEARSAL_LEAD_S, Rehearsal
from runtime.sinks import Event
from tests.conftest import ROOT
from tests.tiny_models import tiny_model_bytes, write_model


def test_runs_at_its_time_and_a_cancel_or_a_newer_schedule_replaces_it():
    rehearsal, ran = Rehearsal(), []
    start = time.perf_counter()
    rehearsal.schedule(lambda: ran.append(("first", time.perf_counter())), start + 0.05)
    rehearsal.schedule(lambda: ran.append(("second", time.perf_counter())), start + 0.03)  # replaces the first
    time.sleep(0.15)
    assert [name for name, _ in ran] == ["second"] and ran[0][1] >= start + 0.03 and rehearsal.runs == 1
    rehearsal.schedule(lambda: ran.append(("cancelled", 0.0)), time.perf_counter() + 0.03)
    rehearsal.cancel()
    rehearsal.schedule(lambda: 1 / 0, time.perf_counter())  # a failing run does not stop the thread
    time.sleep(0.1)
    rehearsal.schedule(lambda: ran.append(("after", 0.0)), time.perf_counter())
    time.sleep(0.05)
    assert [name for name, _ in ran] == ["second", "after"]


def test_daemon_rehearses_before_each_due_frame_with_the_same_decisions(tmp_path):
    """Frames at 32 Hz in real time around two pushes: one rehearsal before each decision (none
    per frame), and the decisions of a daemon that never rehearses."""
    write_model(tmp_path, "m.onnx", tiny_model_bytes())
    layout = SensorLayout.sdh2()
    column = int(layout.columns("distal")[40])
    levels = [0] * 5 + ([900] * 20 + [0] * 45) * 2
    runs = []
    for rehearse in (True, False):
        events: list[Event] = []
        daemon = Daemon(config_from_dict({"sinks": {"stdout": False}}), on_event=events.append)
        daemon.serve(load_model(tmp_path / "m.onnx"), layout)
        if not rehearse:
            daemon.rehearsal.schedule = lambda run, at: None
        for i, level in enumerate(levels):
            values = np.zeros(layout.n_taxels, dtype=np.uint16)
            values[column] = level
            if rehearse and i and daemon._pending and daemon._pending[0] == i:
                # the due frame comes one period after the one before: its rehearsal has run by then
                # (waited for, not slept, so a busy machine cannot make the count flaky)
                expected, deadline = daemon.rehearsal.runs + 1, time.perf_counter() + 5.0
                while daemon.rehearsal.runs < expected and time.perf_counter() < deadline:
                    time.sleep(0.002)
            daemon.handle_frame(Frame(i, round(i * 31.25), time.perf_counter(), values))
        runs.append((daemon.rehearsal.runs, [(e.cls, e.frame_last, e.scores) for e in events]))
    (rehearsals, with_rehearsal), (_, without) = runs
    assert len(with_rehearsal) == 2 and rehearsals == 2 and with_rehearsal == without
    assert 0 < REHEARSAL_LEAD_S < 0.25 / 32


def _daemon_with_a_rehearsal_scheduled(folder) -> Daemon:
    """A daemon fed a push until the frame before a due one: a rehearsal is scheduled a period ahead."""
    folder.mkdir(exist_ok=True)
    write_model(folder, "m.onnx", tiny_model_bytes())
    layout = SensorLayout.sdh2()
    column = int(layout.columns("distal")[40])
    daemon = Daemon(config_from_dict({"sinks": {"stdout": False}}))
    daemon.serve(load_model(folder / "m.onnx"), layout)
    for i, level in enumerate([0] * 5 + [900] * 40):
        values = np.zeros(layout.n_taxels, dtype=np.uint16)
        values[column] = level
        daemon.handle_frame(Frame(i, round(i * 31.25), time.perf_counter(), values))
        if daemon._pending and daemon._pending[0] == i + 1:
            return daemon
    raise AssertionError("no window became due")


def test_a_reconnect_or_a_model_swap_mid_window_drops_the_scheduled_rehearsal(tmp_path):
    daemon = _daemon_with_a_rehearsal_scheduled(tmp_path)
    daemon._fit_layout(daemon.layout)  # the device reconnected (same layout): the history is forgotten
    other = _daemon_with_a_rehearsal_scheduled(tmp_path / "b")
    other._use_model(load_model(tmp_path / "m.onnx"))  # SIGHUP or the watcher swapped a model in
    time.sleep(2 * daemon.period_s)
    assert daemon.rehearsal.runs == 0 and other.rehearsal.runs == 0


def test_dropped_daemons_leave_no_rehearsal_thread_and_shutdown_ends_it(tmp_path, monkeypatch):
    """Replays and benchmarks make a daemon per stream and never call shutdown; the service does."""
    monkeypatch.setattr(rehearsal_module, "IDLE_S", 0.1, raising=False)
    before = threading.active_count()
    peak = before
    for k in range(20):
        _daemon_with_a_rehearsal_scheduled(tmp_path / str(k))
        peak = max(peak, threading.active_count())
    assert peak > before  # each scheduled rehearsal has its thread ...
    deadline = time.perf_counter() + 5.0
    while threading.active_count() > before and time.perf_counter() < deadline:
        time.sleep(0.01)
    assert threading.active_count() == before  # ... and every one ends once idle
    daemon = _daemon_with_a_rehearsal_scheduled(tmp_path / "last")
    monkeypatch.setattr(rehearsal_module, "IDLE_S", 60.0, raising=False)
    time.sleep(0.1)  # rehearsed; idle now
    started = time.perf_counter()
    daemon.shutdown()
    while threading.active_count() > before and time.perf_counter() - started < 5.0:
        time.sleep(0.01)
    assert threading.active_count() == before and time.perf_counter() - started < 2.0  # not IDLE_S (60 s)


EXIT_DURING_A_REHEARSAL = """
import threading, time, onnxruntime as ort
from trainer.bench import hostile_models as H
from runtime.rehearsal import Rehearsal
session, window, started = ort.InferenceSession(H.slow(20_000)), H.pressed_window(), threading.Event()
rehearsal = Rehearsal()
rehearsal.schedule(lambda: (started.set(), session.run(None, {"frames": window})), time.perf_counter())
started.wait(10)
rehearsal.close()  # what Daemon.shutdown does; then the process exits
"""


def test_the_process_exits_cleanly_when_stopped_during_a_rehearsal():
    """onnxruntime aborts a process that exits while another thread runs a session (SIGABRT,
    "terminate called without an active exception"): a SIGTERM during a rehearsal did that."""
    done = subprocess.run([sys.executable, "-c", EXIT_DURING_A_REHEARSAL], cwd=ROOT, capture_output=True, text=True,
                          timeout=120, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert done.returncode == 0 and "terminate called" not in done.stderr, (done.returncode, done.stderr[-300:])
