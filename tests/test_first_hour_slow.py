"""Issue 15, the first hour with real installs (slow: each builds a fresh environment).

- the README's path from a fresh clone of this branch: ``./dev handover simulate``, ``train``,
  the safe drop, the shipped config changed only in device URL and folders, the daemon, events;
- the daemon's lean install (``pip install .``, no extras): what runs, and the one line that
  says which extra the other commands need.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.test_first_hour import drop_model, events_from_daemon, shipped_config
from tests.tiny_models import tiny_model_bytes, write_model

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow


def _run(cmd: list[str], cwd: Path, timeout: float = 1800) -> subprocess.CompletedProcess:
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, f"{cmd}:\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
    return proc


def test_readme_path_from_a_fresh_clone(tmp_path):
    branch = _run(["git", "rev-parse", "--abbrev-ref", "HEAD"], ROOT).stdout.strip()
    clone = tmp_path / "tactile-handover"
    _run(["git", "clone", "--quiet", "--branch", branch, str(ROOT), str(clone)], tmp_path)
    user = tmp_path / "lab"  # the user works in their own folder, not in the checkout
    user.mkdir()
    dev = [sys.executable, str(clone / "dev"), "handover"]
    setup = _run([*dev, "simulate", "--out", "rec", "--subjects", "2", "--runs", "1"], user)
    assert "BuildBackendWarning" not in setup.stderr and "deprecated" not in setup.stderr, setup.stderr[-3000:]
    trained = _run([*dev, "train", "--data", "rec", "--out", "report", "--K", "6", "--repeats", "2", "--no-sweep"],
                   user)
    assert "leave one subject out:" in trained.stdout and (user / "report" / "model.onnx").is_file()
    assert not (clone / "report").exists()
    cfg = shipped_config(user / "deploy", "sim://?events=8&realtime=0&loop=0")
    drop_model(user / "report" / "model.onnx", user / "deploy" / "models")
    handover = str(clone / ".venv" / "bin" / "handover")
    _run([handover, "run", "--config", str(cfg), "--check", "--require-model"], user)
    events = events_from_daemon([handover, "run", "--config", str(cfg)], 3, user)
    assert {e["class"] for e in events} <= {"pull", "push", "hold", "bump"}


def test_lean_install_by_the_offline_route(tmp_path):
    """deploy/INSTALL.md section 0: `pip wheel` on the workstation, `--no-index --find-links` on the
    robot PC (pip's own config switched off there, so only the wheelhouse can serve)."""
    wheels = tmp_path / "handover-install" / "wheels"
    built = _run([sys.executable, "-m", "pip", "wheel", "-q", "--wheel-dir", str(wheels), str(ROOT)], tmp_path)
    assert "BuildBackendWarning" not in built.stderr, built.stderr[-3000:]
    venv = tmp_path / "lean"
    _run([sys.executable, "-m", "venv", str(venv)], tmp_path)
    offline = {**os.environ, "PIP_CONFIG_FILE": os.devnull}
    proc = subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "install", "-q", "--no-index", "--find-links",
                           str(wheels), "tactile-handover"], capture_output=True, text=True, cwd=tmp_path, env=offline)
    assert proc.returncode == 0, proc.stderr[-3000:]
    handover = str(venv / "bin" / "handover")
    for name in ("train", "verify", "plot", "demo", "sweep"):
        proc = subprocess.run([handover, name, "--out", "x"], capture_output=True, text=True, cwd=tmp_path)
        lines = proc.stderr.strip().splitlines()
        assert proc.returncode == 2 and len(lines) == 1, (name, proc.stderr)
        assert "pip install 'tactile-handover[train]'" in lines[0] and "Traceback" not in proc.stderr
    listing = _run([handover, "--help"], tmp_path).stdout
    assert "train" in listing and "[needs tactile-handover[train]]" in listing
    # what the lean install is for: the daemon, a model card, the link check
    models = tmp_path / "deploy" / "models"
    cfg = shipped_config(tmp_path / "deploy", "sim://?events=4&realtime=0&loop=0")
    model = write_model(models, "m.onnx", tiny_model_bytes())
    assert "detects: pull, push, hold, bump" in _run([handover, "inspect", str(model)], tmp_path).stdout
    assert "would serve model" in _run([handover, "run", "--config", str(cfg), "--check"], tmp_path).stdout
    assert "frames" in _run([handover, "dump", "sim://?realtime=0", "--frames", "5"], tmp_path).stdout
