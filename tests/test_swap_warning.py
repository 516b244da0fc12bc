"""A model swap that changes the trigger, the pads or the classes is a WARNING saying from what to
what, and the health file shows the trigger serving now; every event and model line names the
daemon (``instance``). A real daemon process on the simulated hand, models dropped into its folder."""

from __future__ import annotations

import functools
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from tests.tiny_models import tiny_model_bytes, write_model
from tests.waiting import wait_for

ROOT = Path(__file__).resolve().parents[1]


_wait = functools.partial(wait_for, timeout=60.0)


def _health(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def test_a_swap_to_the_papers_trigger_warns_and_the_health_file_shows_it(tmp_path):
    models = tmp_path / "models"
    models.mkdir()
    write_model(models, "onset.onnx", tiny_model_bytes(trigger={"kind": "onset"}), mtime=time.time() - 10)
    health = tmp_path / "status.json"
    cfg = tmp_path / "h.toml"
    cfg.write_text(f'health_file = "{health}"\ninstance = "left-hand"\n[device]\nurl = "sim://?seed=0&events=40"\n'
                   f'[model]\nfolder = "{models}"\npoll_interval_s = 0.1\n[sinks]\nstdout = true\n')
    (tmp_path / "run").mkdir()
    err = (tmp_path / "err.log").open("w")
    out = (tmp_path / "out.log").open("w")
    proc = subprocess.Popen([sys.executable, "-m", "runtime.cli", "run", "--config", str(cfg)], stdout=out, stderr=err,
                            env=dict(os.environ, PYTHONPATH=str(ROOT), XDG_RUNTIME_DIR=str(tmp_path / "run")), cwd=ROOT)
    try:
        assert _wait(lambda: (_health(health).get("trigger") or "").startswith("onset ("))
        assert _health(health)["instance"] == "left-hand"
        # the paper's model: recorded without a kind (the threshold), other pads, a fifth class
        write_model(models, "paper.onnx", tiny_model_bytes(pads=(0, 1, 2, 3, 4, 5), pad_sizes=(84, 78) * 3,
                                                           classes=("pull", "push", "hold", "bump", "dormant"),
                                                           trigger={"fraction": 0.15}))
        assert _wait(lambda: (_health(health).get("trigger") or "").startswith("threshold (fraction 0.15"))
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=20)
        err.close()
        out.close()
    log = (tmp_path / "err.log").read_text()
    warnings = [line for line in log.splitlines() if "WARNING" in line and "changes what is reported" in line]
    assert len(warnings) == 1, log
    assert "paper.onnx" in warnings[0] and "trigger onset (" in warnings[0] and "-> threshold (fraction 0.15" in warnings[0]
    assert "pads [1, 3, 5] -> [0, 1, 2, 3, 4, 5]" in warnings[0] and "'dormant']" in warnings[0]
    lines = [json.loads(x) for x in (tmp_path / "out.log").read_text().splitlines() if x.startswith("{")]
    assert [x["type"] for x in lines].count("model") == 2
    assert all(x["instance"] == "left-hand" for x in lines)
