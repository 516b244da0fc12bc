"""The model line names the model it replaces, also when a reload took the serving model out first.

A stranger switched a running daemon to ``scene.mode = "continuous"`` (SIGHUP) while a model without a
dormant class served: the older model with a dormant class took over, but its ``model`` line said
``previous_model_id: null`` at ``model_version`` 3 (docs/EVENTS.md: null only for the first one), and the
rejection line said "the model in use keeps serving" while none did.
"""

from __future__ import annotations

import io
import json
import logging
import time

import pytest

from firmware_io.layout import SensorLayout
from runtime.config import load_config
from runtime.daemon import Daemon
from tests.tiny_models import tiny_model_bytes, write_model

pytest.importorskip("onnx")


def _model_lines(stream: io.StringIO) -> list[dict]:
    lines = [json.loads(line) for line in stream.getvalue().splitlines() if line.strip()]
    return [line for line in lines if line["type"] == "model"]


def test_a_reload_to_continuous_announces_the_dormant_model_as_replacing_the_one_that_served(tmp_path, caplog):
    models = tmp_path / "models"
    models.mkdir()
    dormant = tiny_model_bytes(classes=("pull", "push", "hold", "bump", "dormant"), dormant_class="dormant")
    write_model(models, "stream.onnx", dormant, mtime=time.time() - 60)
    write_model(models, "plain.onnx", tiny_model_bytes(tag="plain"))
    config = tmp_path / "handover.toml"
    base = f'[device]\nurl = "sim://"\n[model]\nfolder = "{models}"\npoll_interval_s = 0.05\n'
    config.write_text(base)
    stream = io.StringIO()
    daemon = Daemon(load_config(config), stream=stream)
    try:
        daemon.layout = SensorLayout.sdh2()
        daemon._start_watcher()
        daemon.watcher.stop()
        plain_id = daemon.model.model_id
        config.write_text(base + '[scene]\nmode = "continuous"\n')
        with caplog.at_level(logging.ERROR, logger="handover.models"):
            daemon._do_reload()
            daemon.watcher.poll(require_stable=False)  # the watcher thread's next scan
        daemon._take_pending_model(time.monotonic())
    finally:
        daemon.watcher.stop()
        daemon.sinks.close()
    first, second = _model_lines(stream)
    assert second["model_file"] == "stream.onnx" and second["model_version"] == 2
    assert first["previous_model_id"] is None and second["previous_model_id"] == plain_id
    (rejected,) = [r.getMessage() for r in caplog.records if "rejected" in r.getMessage()]
    assert "plain.onnx" in rejected and "the model in use keeps serving" not in rejected, rejected
    assert "no model serves yet" in rejected
