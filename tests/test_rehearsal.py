"""The rehearsal (runtime.rehearsal): the model runs once shortly before a due frame, in a thread,
and never changes a decision."""

from __future__ import annotations

import time

import numpy as np

from firmware_io.client import Frame
from firmware_io.layout import SensorLayout
from runtime.config import config_from_dict
from runtime.daemon import Daemon
from runtime.model import load_model
from runtime.rehearsal import REHEARSAL_LEAD_S, Rehearsal
from runtime.sinks import Event
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
                time.sleep(daemon.period_s)  # the due frame comes one period after the one before
            daemon.handle_frame(Frame(i, round(i * 31.25), time.perf_counter(), values))
        runs.append((daemon.rehearsal.runs, [(e.cls, e.frame_last, e.scores) for e in events]))
    (rehearsals, with_rehearsal), (_, without) = runs
    assert len(with_rehearsal) == 2 and rehearsals == 2 and with_rehearsal == without
    assert 0 < REHEARSAL_LEAD_S < 0.25 / 32
