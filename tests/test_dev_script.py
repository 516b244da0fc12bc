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


def test_a_corrupt_stamp_reinstalls_and_never_crashes(tmp_path, monkeypatch, capsys):
    """A stamp of binary junk raised UnicodeDecodeError; one whose extras field was junk (``,train``
    or ``x;y``) was carried into every later install, so pip refused ``[,train]`` on every ./dev."""
    dev, installs = _dev(tmp_path, monkeypatch)
    dev.ensure_env("train,dev")
    stamp = tmp_path / ".venv" / ".installed"
    digest = stamp.read_text().split()[0]
    for junk in (b"\xff\xfe\x00junk", b"", b"\n\n", f"{digest} ,train".encode(), f"{digest} x;y,train".encode(),
                 f"  {digest}\n dev,train \n".encode()):
        stamp.write_bytes(junk)
        dev.ensure_env("train,dev")
        assert all(e and all(n.replace("-", "").replace("_", "").isalnum() for n in e.split(","))
                   for e in installs), installs
        assert installs[-1] == "dev,train"
    stamp.unlink()
    stamp.mkdir()  # not even a file: install and say so, no traceback
    try:
        dev.ensure_env("train,dev")
    except SystemExit as exc:
        assert ".installed" in str(exc)


def test_a_failed_install_is_one_line_not_a_traceback(tmp_path, monkeypatch):
    dev, _ = _dev(tmp_path, monkeypatch)

    def fails(cmd) -> None:
        raise dev.subprocess.CalledProcessError(1, cmd)

    monkeypatch.setattr(dev.subprocess, "check_call", fails)
    import pytest

    with pytest.raises(SystemExit) as exc:
        dev.ensure_env("train,dev")
    assert "pip" in str(exc.value) and "\n" not in str(exc.value)
    assert not (tmp_path / ".venv" / ".installed").exists()


def test_python_deleted_with_a_stamp_present_reinstalls(tmp_path, monkeypatch):
    dev, installs = _dev(tmp_path, monkeypatch)
    dev.ensure_env("train,dev,bench")
    (tmp_path / ".venv" / "bin" / "python").unlink()
    monkeypatch.setattr(dev.venv, "EnvBuilder", lambda **_: type("B", (), {"create": lambda self, p: (
        Path(p, "bin").mkdir(parents=True, exist_ok=True), Path(p, "bin", "python").write_text(""))})())
    dev.ensure_env("train,dev")
    assert len(installs) == 2 and installs[-1] == "dev,train"


def test_install_md_ros_section_keeps_a_checkout_editable_and_matches_dev():
    """deploy/INSTALL.md's ROS 2 step: every pip install of a checkout or of '.' is editable (-e),
    or goes into the robot PC's own venv (/opt/handover); ./dev already installs the ros extra, as
    the section says. A plain `.venv/bin/pip install '.[ros]'` turned the checkout into a copy."""
    import re
    import shlex

    loader = importlib.machinery.SourceFileLoader("dev_script_extras", str(ROOT / "dev"))
    spec = importlib.util.spec_from_loader("dev_script_extras", loader)
    dev = importlib.util.module_from_spec(spec)
    loader.exec_module(dev)
    assert "ros" in dev.EXTRAS.split(",")
    text = (ROOT / "deploy" / "INSTALL.md").read_text()
    section = text[text.index("## ROS 2"):]
    section = section[: section.index("\n## ", 5)]
    assert "./dev` already installs the `ros` extra" in section
    allowed = section.replace("`.venv/bin/pip install '.[ros]'` there", "")  # the warning names it
    commands = re.findall(r"(\S*pip (?:install|wheel) [^`\n#]*)", allowed)
    assert len(commands) >= 3
    for command in commands:
        words = shlex.split(command.replace('"', "").replace("$SRC", "SRC"))
        into_opt = words[0].startswith("/opt/handover/")
        assert into_opt or "-e" in words or words[1] == "wheel", f"{command!r} would replace an editable checkout by a copy"
