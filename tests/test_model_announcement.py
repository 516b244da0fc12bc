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
from tests.tiny_models import dormant_then_plain, tiny_model_bytes, write_model

pytest.importorskip("onnx")


def _model_lines(stream: io.StringIO) -> list[dict]:
    lines = [json.loads(line) for line in stream.getvalue().splitlines() if line.strip()]
    return [line for line in lines if line["type"] == "model"]


def test_a_reload_to_continuous_announces_the_dormant_model_as_replacing_the_one_that_served(tmp_path, caplog):
    models = dormant_then_plain(tmp_path)
    config = tmp_path / "handover.toml"
    base = f'[device]\nurl = "sim://"\n[model]\nfolder = "{models}"\npoll_interval_s = 0.05\n'
    config.write_text(base)
    stream = io.StringIO()
    daemon = Daemon(load_config(config), stream=stream)
    try:
        daemon.detector.fit(SensorLayout.sdh2())
        daemon.models.start()
        daemon.models.watcher.stop()
        plain_id = daemon.model.model_id
        config.write_text(base + '[scene]\nmode = "continuous"\n')
        with caplog.at_level(logging.ERROR, logger="handover.models"):
            daemon.reload()
            daemon.models.watcher.poll(require_stable=False)  # the watcher thread's next scan
        daemon.take_pending_model(time.monotonic())
    finally:
        daemon.models.watcher.stop()
        daemon.sinks.close()
    first, second = _model_lines(stream)
    assert second["model_file"] == "stream.onnx" and second["model_version"] == 2
    assert first["previous_model_id"] is None and second["previous_model_id"] == plain_id
    (rejected,) = [r.getMessage() for r in caplog.records if "rejected" in r.getMessage()]
    assert "plain.onnx" in rejected and "the model in use keeps serving" not in rejected, rejected
    assert "no model serves yet" in rejected


def test_the_swap_line_says_which_trigger_the_new_model_brings(tmp_path, caplog):
    """A stranger dropped a threshold-cut model onto a daemon serving an onset model: the trigger changed
    with it (settings come from the model), but the swap line did not say so."""
    models = tmp_path / "models"
    models.mkdir()
    write_model(models, "onset.onnx", tiny_model_bytes(trigger={"kind": "onset"}), mtime=time.time() - 60)
    config = tmp_path / "handover.toml"
    config.write_text(f'[device]\nurl = "sim://"\n[sinks]\nstdout = false\n[model]\nfolder = "{models}"\n')
    daemon = Daemon(load_config(config))
    try:
        with caplog.at_level(logging.INFO, logger="handover.daemon"):
            daemon.detector.fit(SensorLayout.sdh2())
            daemon.models.start()
            write_model(models, "paper.onnx", tiny_model_bytes(tag="paper"))  # no kind: the paper's threshold
            daemon.models.watcher.poll(require_stable=False)
            daemon.take_pending_model(time.monotonic())
    finally:
        daemon.models.watcher.stop()
        daemon.sinks.close()
    serving, swapped = [r.getMessage() for r in caplog.records if r.name == "handover.daemon" and r.levelno == logging.INFO]
    assert "onset.onnx" in serving and "onset trigger" in serving, serving
    assert "paper.onnx" in swapped and "threshold trigger" in swapped and "swapped in" in swapped, swapped
    (warning,) = [r.getMessage() for r in caplog.records if r.name == "handover.daemon" and r.levelno == logging.WARNING]
    assert "paper.onnx changes what is reported: trigger onset (" in warning and "-> threshold (fraction 0.15" in warning
    assert daemon.health.trigger.startswith("threshold (fraction 0.15")
