"""The one way a command reports a user error: ``handover CMD: message`` on stderr, an exit code."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_no_command_defines_its_own_fail():
    """Every command raises a HandoverError that handover's main prints; a private printer would drift."""
    copies = [str(p.relative_to(ROOT)) for pkg in ("firmware_io", "runtime", "trainer")
              for p in (ROOT / pkg).rglob("*.py") if re.search(r"def _?fail\(", p.read_text())]
    assert copies == []


def test_a_command_error_through_the_entry_point():
    proc = subprocess.run([sys.executable, "-m", "runtime.cli", "dump", "sim://", "--frames", "0"], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and proc.stderr.startswith("handover dump: argument --frames: must be at least 1, got 0")


def _own_modules():
    import importlib
    import pkgutil

    for pkg in ("firmware_io", "runtime", "trainer"):
        for info in pkgutil.walk_packages([str(ROOT / pkg)], prefix=f"{pkg}."):
            if ".bench" in info.name or info.name.endswith("__main__"):
                continue
            try:
                yield importlib.import_module(info.name)
            except ImportError:  # an optional extra (ROS 2, usb) not installed here
                continue


def test_every_error_class_of_the_packages_derives_from_the_one_root():
    """main catches HandoverError once; an error class outside it would end in a traceback."""
    from firmware_io.errors import HandoverError

    outside = sorted(f"{m.__name__}.{name}" for m in _own_modules() for name, obj in vars(m).items()
                     if isinstance(obj, type) and issubclass(obj, BaseException) and obj.__module__ == m.__name__
                     and not issubclass(obj, HandoverError))
    assert outside == []


def test_a_raised_error_is_one_line_with_its_exit_code(monkeypatch, capsys):
    import types

    from firmware_io.errors import DeviceFailure, HandoverError, Interrupted
    from runtime import cli

    for error, code in ((HandoverError("--x: give a folder"), 2), (DeviceFailure("--x: give a folder"), 1),
                        (Interrupted("--x: give a folder"), 130)):
        def main(args, error=error):
            raise error
        module = types.SimpleNamespace(add_arguments=lambda parser: None, main=main)
        monkeypatch.setattr(cli.importlib, "import_module", lambda name, module=module: module)
        assert cli.main(["dump"]) == code
        assert capsys.readouterr().err == "handover dump: --x: give a folder\n"


def test_builtin_bases_are_kept():
    """`except ValueError` written before the root still catches a recording error."""
    from firmware_io.recordings.recording import RecordingError
    from firmware_io.transports import DeviceUnavailable, TransportError

    assert issubclass(RecordingError, ValueError) and issubclass(TransportError, OSError)
    assert TransportError("bad URL").exit_code == 2 and DeviceUnavailable("unplugged").exit_code == 1


@pytest.mark.parametrize(("kind", "text", "words"), [("float", "nan", "must be a positive number, got nan"),
                                                     ("float", "0", "must be a positive number, got 0"),
                                                     ("float", "x", "expected a positive number, got 'x'"),
                                                     ("int", "0", "must be in 1..3, got 0"),
                                                     ("int", "4", "must be in 1..3, got 4")])
def test_range_types_refuse_with_one_message(kind, text, words):
    import argparse

    from firmware_io.commands.options import int_in, positive_float

    read = positive_float if kind == "float" else int_in(1, 3)
    with pytest.raises(argparse.ArgumentTypeError, match=words.replace("(", r"\(").replace(".", r"\.")):
        read(text)


def test_out_folder_refuses_a_file_in_one_line(tmp_path):
    from firmware_io.commands.options import out_folder
    from firmware_io.errors import HandoverError

    (tmp_path / "file").write_text("")
    with pytest.raises(HandoverError, match="is a file, not a folder"):
        out_folder(tmp_path / "file")
    with pytest.raises(HandoverError, match=re.escape(f"{tmp_path / 'file'} is a file, not a folder")):  # a folder inside it
        out_folder(tmp_path / "file" / "below")
    assert out_folder(tmp_path / "new" / "deep") == tmp_path / "new" / "deep"


@pytest.mark.parametrize("argv", [["record", "--device", "sim://", "--subject", "s1"], ["train"], ["sweep"],
                                  ["plot", "x.hrec"]])
@pytest.mark.parametrize("level", ["0", "1.5", "nan", "abc"])
def test_a_trigger_level_outside_0_1_is_refused_as_it_is_read(argv, level, capsys):
    """record checked --fraction by hand after parsing; train, sweep and plot went on with it."""
    from runtime.cli import main

    with pytest.raises(SystemExit) as stop:
        main([*argv, "--fraction", level])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and err.count("\n") == 1
    assert f"argument --fraction: must be a fraction of full scale in (0, 1), e.g. 0.15, got '{level}'" in err


def test_a_failed_command_takes_back_the_empty_out_folder_it_made_and_keeps_others(tmp_path, capsys):
    from runtime.cli import main

    data = tmp_path / "data"
    data.mkdir()
    (tmp_path / "kept").mkdir()
    assert main(["train", "--data", str(data), "--out", str(tmp_path / "new" / "report")]) == 2
    assert main(["train", "--data", str(data), "--out", str(tmp_path / "kept")]) == 2
    (tmp_path / "old" / "a").mkdir(parents=True)  # named through a folder that does not exist: only that is new
    assert main(["train", "--data", str(data), "--out", str(tmp_path / "gone" / ".." / "old" / "a")]) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data", "kept", "old"] and (tmp_path / "old" / "a").is_dir()
    from firmware_io.commands.options import _to_make

    real = tmp_path.resolve()
    assert _to_make(tmp_path / "new" / "deep") == [real / "new" / "deep", real / "new"]
    assert "no .hrec recordings" in capsys.readouterr().err


def test_wrong_paths_say_what_to_give_instead(tmp_path, capsys):
    from runtime.cli import main

    (tmp_path / "m").mkdir()
    (tmp_path / "m" / "model.onnx").write_bytes(b"")
    (tmp_path / "bad.hrec").write_bytes(b"junk")
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "bad.hrec").write_bytes(b"junk")
    assert main(["inspect", str(tmp_path / "m")]) == 2
    assert main(["train", "--data", str(tmp_path / "bad.hrec"), "--out", str(tmp_path / "r")]) == 2
    assert main(["train", "--data", str(tmp_path / "d"), "--out", str(tmp_path / "r")]) == 2
    said = capsys.readouterr().err.splitlines()
    assert said[0].endswith("a folder, not a model file; give the .onnx file in it (model.onnx)"), said
    assert said[1].endswith(f"a file, not a folder; give the folder that holds the recordings ({tmp_path})"), said
    assert said[2].endswith(f"move it out of {tmp_path / 'd'} (or record it again) and train again"), said
    assert not (tmp_path / "r").exists()


@pytest.mark.skipif(not hasattr(__import__("os"), "mkfifo"), reason="no FIFOs on this system")
def test_devices_and_fifos_are_refused_as_models_and_recordings_without_blocking(tmp_path, capsys):
    import os

    from runtime.cli import main

    os.mkfifo(tmp_path / "fifo.onnx")
    data = tmp_path / "data"
    data.mkdir()
    os.mkfifo(data / "a.hrec")
    (tmp_path / "zero.onnx").symlink_to("/dev/zero")
    assert main(["inspect", str(tmp_path / "fifo.onnx")]) == 2  # opened without waiting for a writer
    assert main(["inspect", str(tmp_path / "zero.onnx")]) == 2  # never read whole
    assert main(["train", "--data", str(data), "--out", str(tmp_path / "r")]) == 2
    said = capsys.readouterr().err.splitlines()
    assert len(said) == 3 and all("not a regular file (a device, FIFO or socket)" in line for line in said), said
