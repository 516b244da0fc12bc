"""./dev's set-up: .venv is installed once per pyproject.toml, extras installed before are kept (a
stranger's ./dev bench then ./dev test reinstalled every time and the skips changed with it)."""

from __future__ import annotations

import importlib.machinery
import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _dev(tmp_path, monkeypatch):
    loader = importlib.machinery.SourceFileLoader("dev_script", str(ROOT / "dev"))
    spec = importlib.util.spec_from_loader("dev_script", loader)
    dev = importlib.util.module_from_spec(spec)
    loader.exec_module(dev)
    (tmp_path / "pyproject.toml").write_text("[project]\nname = 'x'\n")
    venv = tmp_path / ".venv"
    monkeypatch.setattr(dev, "ROOT", tmp_path)
    monkeypatch.setattr(dev, "VENV", venv)
    monkeypatch.setattr(dev, "PY", venv / "bin" / "python")
    installs: list[str] = []

    class Builder:
        def __init__(self, **_) -> None:
            pass

        def create(self, path) -> None:
            (Path(path) / "bin").mkdir(parents=True)
            (Path(path) / "bin" / "python").write_text("")

    def check_call(cmd) -> None:
        if cmd[-1].startswith(str(tmp_path)):
            installs.append(cmd[-1].split("[")[1].rstrip("]"))

    monkeypatch.setattr(dev.venv, "EnvBuilder", Builder)
    monkeypatch.setattr(dev.subprocess, "check_call", check_call)
    return dev, installs


def test_extras_accumulate_and_nothing_is_reinstalled_for_fewer(tmp_path, monkeypatch, capsys):
    dev, installs = _dev(tmp_path, monkeypatch)
    dev.ensure_env("train,dev")
    dev.ensure_env("train,dev")
    dev.ensure_env("train,dev,bench")  # ./dev bench
    dev.ensure_env("train,dev")  # ./dev test afterwards: bench stays, nothing to do
    assert installs == ["dev,train", "bench,dev,train"]
    (tmp_path / "pyproject.toml").write_text("[project]\nname = 'y'\n")  # a dependency changed
    dev.ensure_env("train,dev")
    assert installs[-1] == "bench,dev,train"
