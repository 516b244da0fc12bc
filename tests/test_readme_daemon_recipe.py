"""README "The daemon without a hand", run as written in a shell with umask 002 (a common default):
the copied model must be mode 644 so that the daemon serves it (the watcher refuses a model file
others could change), and ``--check`` must say so, with the exact command, when a copy is not."""

from __future__ import annotations

import os
import re
import stat
import subprocess

from runtime.cli import main as handover
from tests.conftest import ROOT
from tests.tiny_models import tiny_model_bytes


def recipe_lines() -> list[str]:
    text = (ROOT / "README.md").read_text()
    section = text[text.index("## The daemon without a hand"):]
    block = re.search(r"```sh\n(.*?)```", section, re.S).group(1)
    return block.splitlines()


def test_recipe_installs_the_model_mode_644_under_umask_002(tmp_path, capsys):
    lines = recipe_lines()
    setup = [ln for ln in lines if "emulate" not in ln and "handover run" not in ln]  # no device, no daemon
    model = tmp_path / "out" / "demo" / "report" / "stream-model.onnx"
    model.parent.mkdir(parents=True)
    model.write_bytes(tiny_model_bytes())
    os.chmod(model, 0o664)  # as ./dev demo writes it under umask 002
    subprocess.run(["bash", "-ec", "umask 002\n" + "\n".join(setup)], cwd=tmp_path, check=True)
    copied = tmp_path / "try" / "models" / "stream-model.onnx"
    assert stat.S_IMODE(copied.stat().st_mode) == 0o644
    assert handover(["run", "--config", str(tmp_path / "try" / "handover.toml"), "--check"]) == 0
    out = capsys.readouterr()
    others = [line for line in out.err.splitlines() if "warning: stream setting" not in line]  # a tiny model: unmeasured
    assert "would serve model" in out.out and not others, out.err


def test_check_says_exactly_how_to_fix_a_group_writable_model(tmp_path, capsys):
    folder = tmp_path / "models"
    folder.mkdir()
    path = folder / "m.onnx"
    path.write_bytes(tiny_model_bytes())
    os.chmod(path, 0o664)
    config = tmp_path / "c.toml"
    config.write_text(f'[device]\nurl = "sim://"\n[model]\nfolder = "{folder}"\n')
    assert handover(["run", "--config", str(config), "--check"]) == 0
    err = capsys.readouterr().err
    assert f"writable by group or others (mode 664, e.g. copied under umask 002): run chmod 644 {path}" in err
