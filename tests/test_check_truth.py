"""``handover run --check`` tells the truth (issue 18 item 4, issue 15 item 1): a model folder
that is a file or unreadable, and pads the SDH-2 does not have, are errors (exit 2), and the model
it names is the one the daemon serves (the last dropped, whatever its mtime)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.tiny_models import tiny_model_bytes, write_model

pytest.importorskip("onnx")
ROOT = Path(__file__).resolve().parents[1]


def _check(cfg: Path, drop_read_override: bool = False) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "runtime.cli", "run", "--config", str(cfg), "--check"], cwd=ROOT,
                          capture_output=True, text=True, timeout=60,
                          preexec_fn=_without_read_override if drop_read_override else None)


def _without_read_override() -> None:
    """Root without CAP_DAC_OVERRIDE and CAP_DAC_READ_SEARCH reads only what its mode bits allow, while it
    still reaches the interpreter and the checkout however private the clone's folder is (another uid may not)."""
    import ctypes

    prctl = ctypes.CDLL(None, use_errno=True).prctl
    for cap in (1, 2):  # CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH, dropped from the bounding set before exec
        if prctl(24, cap, 0, 0, 0) != 0:  # PR_CAPBSET_DROP
            raise OSError(ctypes.get_errno(), "PR_CAPBSET_DROP")


def _config(folder: Path, models: Path, extra: str = "") -> Path:
    cfg = folder / "h.toml"
    cfg.write_text(f'[device]\nurl = "sim://"\n[model]\nfolder = "{models}"\n{extra}')
    os.chmod(cfg, 0o644)
    return cfg


def _one_error(proc: subprocess.CompletedProcess, needle: str) -> None:
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("handover run: ") and needle in lines[0], proc.stderr


def test_a_model_folder_that_is_a_file_is_an_error(tmp_path):
    not_a_folder = tmp_path / "models"
    not_a_folder.write_text("oops")
    _one_error(_check(_config(tmp_path, not_a_folder)), "is not a folder")


def test_an_unreadable_model_folder_is_an_error(tmp_path):
    if os.geteuid() != 0:
        pytest.skip("needs root to give the model folder to another user (nobody)")
    models = tmp_path / "models"
    models.mkdir(mode=0o700)
    write_model(models, "m.onnx", tiny_model_bytes())
    os.chown(models, 65534, 65534)
    cfg = _config(tmp_path, models)
    try:
        probe = subprocess.run([sys.executable, "-c", f"import os; os.listdir({str(models)!r})"],
                               capture_output=True, preexec_fn=_without_read_override)
    except (OSError, subprocess.SubprocessError):
        probe = None
    if probe is None or probe.returncode == 0:
        pytest.skip("cannot drop root's read override here (no CAP_SETPCAP, or it is inherited)")
    _one_error(_check(cfg, drop_read_override=True), "model.folder: cannot read")


def test_pads_the_sdh2_does_not_have_are_an_error(tmp_path):
    models = tmp_path / "models"
    models.mkdir()
    write_model(models, "m.onnx", tiny_model_bytes())
    _one_error(_check(_config(tmp_path, models, '[scene]\npads = "1,3,9"\n')), "scene.pads")


def test_check_names_the_model_the_daemon_serves_after_a_rollback(tmp_path):
    """v2 and v1 in the folder, v1 rolled back by touching it (the newest mtime): both name v1."""
    from runtime.config import load_config
    from runtime.daemon import Daemon

    models = tmp_path / "models"
    models.mkdir()
    write_model(models, "v2.onnx", tiny_model_bytes(tag="v2"), mtime=time.time() - 100)
    write_model(models, "v1.onnx", tiny_model_bytes(tag="v1"), mtime=time.time() - 86400)
    os.utime(models / "v1.onnx")  # the rollback: touch
    cfg = _config(tmp_path, models, '[sinks]\nstdout = false\n')
    proc = _check(cfg)
    assert proc.returncode == 0 and "(v1.onnx)" in proc.stdout, proc.stdout + proc.stderr
    daemon = Daemon(load_config(cfg))
    daemon.models.start()
    try:
        assert Path(daemon.model.path).name == "v1.onnx"
    finally:
        daemon.models.watcher.stop()


def test_pads_that_follow_the_model_are_not_an_error(tmp_path):
    models = tmp_path / "models"
    models.mkdir()
    write_model(models, "m.onnx", tiny_model_bytes())
    proc = _check(_config(tmp_path, models, '[scene]\npads = "model"\n'))
    assert proc.returncode == 0 and "would serve model" in proc.stdout, proc.stdout + proc.stderr


def test_a_missing_model_folder_is_an_error_an_empty_one_a_warning(tmp_path):
    """A typo in model.folder passed --check (exit 0) and the daemon waited for a folder nobody
    would ever fill; an existing empty folder stays a warning (the daemon waits for a model)."""
    typo = tmp_path / "modles"
    cfg = _config(tmp_path, typo)
    _one_error(_check(cfg), f"model.folder {typo} does not exist: create it (mkdir -p {typo}) or fix the path "
                            f"in {cfg}")
    typo.mkdir()
    proc = _check(cfg)
    assert proc.returncode == 0 and proc.stderr.startswith("handover run: warning: no model in"), proc.stderr


def test_the_running_daemon_waits_for_a_missing_folder_and_serves_once_it_appears(tmp_path, caplog):
    """At run time (not --check) a folder that is missing, or removed later, is waited for, said once."""
    import logging

    from runtime.config import config_from_dict
    from runtime.daemon import Daemon
    from tests.test_faults import _run_until

    models = tmp_path / "models"
    # the stream at its real rate: at full speed the hot loop holds the interpreter, and the watcher's
    # warm-up timing of the new model (model.decision_budget) measured that wait, not the model
    cfg = config_from_dict({"device": {"url": "sim://?events=4"},
                            "model": {"folder": str(models), "poll_interval_s": 0.05}, "sinks": {"stdout": False}})
    daemon = Daemon(cfg)
    caplog.set_level(logging.WARNING, logger="handover")
    state = {"made": None}

    def appear(d) -> bool:
        if d.health.frames_received > 50 and state["made"] is None:
            models.mkdir()
            write_model(models, "m.onnx", tiny_model_bytes())
            state["made"] = time.monotonic()
        return d.model is not None

    assert _run_until(daemon, appear, timeout=30), "the model dropped into the new folder was never served"
    missing = [r for r in caplog.records if "does not exist" in r.getMessage()]
    assert len(missing) == 1, [r.getMessage() for r in caplog.records]


def test_a_model_named_with_a_newline_is_named_once_in_repr_and_not_served(tmp_path):
    """The name would have been printed raw in every line about the file (a newline forges a log line)."""
    models = tmp_path / "models"
    models.mkdir()
    write_model(models, "z\nFAKE.onnx", tiny_model_bytes())
    proc = _check(_config(tmp_path, models))
    assert proc.returncode == 0, proc.stderr
    assert "would serve yet ('z\\nFAKE.onnx': control characters in its name (rename it))" in proc.stderr
    assert not any(line.startswith("FAKE") for line in proc.stderr.splitlines())
