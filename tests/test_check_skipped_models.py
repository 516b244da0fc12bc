"""``handover run --check`` names a newer model file it would refuse, not only the older one it would serve.

A stranger switched the config to ``scene.mode = "continuous"`` with a 4-class model dropped last and a
5-class (dormant) one before it: --check said "would serve model ... (stream.onnx)" and nothing about
why the newer file was passed over, while the running daemon logs it as rejected.
"""

from __future__ import annotations

import pytest

from runtime.cli import main as handover
from tests.tiny_models import dormant_then_plain

pytest.importorskip("onnx")


def test_check_warns_about_a_newer_file_it_would_refuse(tmp_path, capsys):
    models = dormant_then_plain(tmp_path)
    config = tmp_path / "handover.toml"
    config.write_text(f'[device]\nurl = "sim://"\n[model]\nfolder = "{models}"\n[scene]\nmode = "continuous"\n')
    assert handover(["run", "--config", str(config), "--check"]) == 0
    out = capsys.readouterr()
    assert "would serve model" in out.out and "(stream.onnx)" in out.out
    (line,) = [ln for ln in out.err.splitlines() if "plain.onnx" in ln]
    assert line.startswith("handover run: warning: plain.onnx") and "dormant class" in line, out.err
