"""The garbage collector runs when the daemon says (runtime.heap): never inside a window."""

from __future__ import annotations

import gc
import threading

from runtime.config import config_from_dict
from runtime.daemon import Daemon
from runtime.heap import CLEARANCE_S, FULL_PERIOD_S, MAX_DEFER_S, YOUNG_PERIOD_S, GarbageSchedule
from runtime.listeners import FrameListener
from tests.tiny_models import tiny_model_bytes, write_model


def test_the_schedule_collects_between_windows_only_and_everything_now_and_then(monkeypatch):
    calls = []
    monkeypatch.setattr(gc, "collect", lambda generation=2: calls.append(generation) or 0)
    garbage = GarbageSchedule()
    garbage.collect(100.0, window_open=True)
    assert calls == []  # a window is open: later
    garbage.collect(100.0, window_open=False)
    garbage.collect(100.0 + YOUNG_PERIOD_S / 2, window_open=False)  # not due yet
    garbage.collect(100.0 + YOUNG_PERIOD_S, window_open=False)
    garbage.collect(100.0 + FULL_PERIOD_S, window_open=False)
    assert calls == [2, 1, 2] and garbage.collections == 3
    # windows open all the time (a trigger that keeps firing): late, but not never
    t = 100.0 + FULL_PERIOD_S + YOUNG_PERIOD_S
    garbage.collect(t + MAX_DEFER_S / 2, window_open=True)
    assert calls == [2, 1, 2]
    garbage.collect(t + MAX_DEFER_S, window_open=True)
    assert calls == [2, 1, 2, 1]


def test_a_due_frame_holds_a_collection_back_only_when_it_is_close(monkeypatch):
    """Continuous mode expects every next frame: right after a decision (30 ms to go at 32 Hz) the
    collection runs; within the clearance it waits, at most MAX_DEFER_S (a stream so fast that every
    frame is always close must still be collected)."""
    calls = []
    monkeypatch.setattr(gc, "collect", lambda generation=2: calls.append(generation) or 0)
    garbage = GarbageSchedule()
    garbage.collect(100.0, window_open=False, due_in=CLEARANCE_S / 2)
    garbage.collect(100.0 + MAX_DEFER_S / 2, window_open=False, due_in=CLEARANCE_S / 2)
    assert calls == []
    garbage.collect(100.0 + MAX_DEFER_S / 2, window_open=False, due_in=0.03)
    assert calls == [2]
    t = 100.0 + MAX_DEFER_S / 2 + YOUNG_PERIOD_S  # the next young collection is due
    garbage.collect(t + MAX_DEFER_S / 2, window_open=False, due_in=0.0)
    assert calls == [2]
    garbage.collect(t + MAX_DEFER_S, window_open=False, due_in=0.0)
    assert calls == [2, 1]


class _GcState(FrameListener):
    def __init__(self) -> None:
        self.enabled: set[bool] = set()

    def on_frame(self, frame) -> None:
        self.enabled.add(gc.isenabled())


def test_no_automatic_collection_while_the_daemon_runs_and_the_default_back_after(tmp_path):
    models = tmp_path / "models"
    models.mkdir()
    write_model(models, "m.onnx", tiny_model_bytes())
    daemon = Daemon(config_from_dict({"device": {"url": "sim://?events=2&realtime=0&loop=0"},
                                      "model": {"folder": str(models)}, "sinks": {"stdout": False}}))
    seen = _GcState()
    daemon.listeners.append(seen)
    stopper = threading.Timer(3.0, daemon.request_stop)
    stopper.start()
    try:
        assert gc.isenabled()
        daemon.run()
    finally:
        stopper.cancel()
        gc.unfreeze()
    assert seen.enabled == {False} and daemon.health.frames_received > 0
    assert gc.isenabled() and daemon.garbage.collections >= 1
