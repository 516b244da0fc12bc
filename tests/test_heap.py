"""The heap at start-up (runtime.heap): start-up's objects are hidden from the collector, which stays on."""

from __future__ import annotations

import gc
import threading

from runtime.config import config_from_dict
from runtime.daemon import Daemon
from runtime.heap import settle_heap
from runtime.listeners import FrameListener
from tests.tiny_models import tiny_model_bytes, write_model


def test_settle_heap_freezes_what_is_alive_and_leaves_collection_on():
    gc.unfreeze()
    alive = [object() for _ in range(10)]
    try:
        settle_heap()
        assert gc.get_freeze_count() >= len(alive) and gc.isenabled()
    finally:
        gc.unfreeze()


class _GcState(FrameListener):
    def __init__(self) -> None:
        self.enabled: set[bool] = set()

    def on_frame(self, frame) -> None:
        self.enabled.add(gc.isenabled())


def test_the_running_daemon_keeps_automatic_collection_on(tmp_path):
    models = tmp_path / "models"
    models.mkdir()
    write_model(models, "m.onnx", tiny_model_bytes())
    daemon = Daemon(config_from_dict({"device": {"url": "sim://?events=2&realtime=0&loop=0"},
                                      "model": {"folder": str(models)}, "sinks": {"stdout": False}}))
    seen = _GcState()
    daemon.listeners.append(seen)
    stopper = threading.Timer(3.0, daemon.request_stop)
    stopper.start()
    gc.unfreeze()
    try:
        daemon.run()
        assert gc.get_freeze_count() > 0
    finally:
        stopper.cancel()
        gc.unfreeze()
    assert seen.enabled == {True} and daemon.health.frames_received > 0
