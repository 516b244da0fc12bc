"""The `handover` entry point: lists commands, refuses unknown ones, never imports the trainer for `run`."""

from __future__ import annotations

import importlib
import subprocess
import sys

from runtime import cli


def test_help_lists_commands(capsys):
    assert cli.main(["--help"]) == 0
    out = capsys.readouterr().out
    assert "usage: handover COMMAND" in out


def test_unknown_command_is_one_clear_error(capsys):
    assert cli.main(["no-such-command"]) == 2
    err = capsys.readouterr().err
    assert "unknown command 'no-such-command'" in err and len(err.strip().splitlines()) == 1
    assert cli.main(["tarin"]) == 2
    assert "did you mean 'handover train'?" in capsys.readouterr().err


def test_a_wrong_option_is_one_line_that_points_at_help(capsys):
    import pytest

    for argv, said in ((["train", "--kernel", "foo"], "argument --kernel: invalid choice: 'foo'"),
                       (["run"], "the following arguments are required: --config")):
        with pytest.raises(SystemExit) as stop:
            cli.main(argv)
        err = capsys.readouterr().err
        assert stop.value.code == 2 and err.count("\n") == 1 and said in err, err
        assert err.startswith(f"handover {argv[0]}: ") and err.rstrip().endswith(f"(see handover {argv[0]} --help)")


def test_an_empty_value_is_refused_by_every_command(capsys):
    """``--out ''`` means the current folder to a Path: ``simulate --out ''`` wrote 84 MB there."""
    import pytest

    for argv, said in ((["train", "--features", "", "--out", "/nonexistent/never-written"], "--features is empty"),
                       (["simulate", "--out", ""], "--out is empty"), (["bench", "latency", "--out", ""], "--out is empty"),
                       (["train", "--data="], "--data is empty"), (["inspect", " "], "an argument is empty")):
        with pytest.raises(SystemExit) as stop:
            cli.main(argv)
        err = capsys.readouterr().err
        assert stop.value.code == 2 and err.count("\n") == 1 and said in err, (argv, err)
    parser = cli.build_parser("demo", importlib.import_module(cli.COMMANDS["demo"][0]))
    assert parser.parse_args(["--fault", ""]).fault == ""  # its default: no faults, as documented


def test_every_command_module_has_the_two_functions():
    import importlib.util

    for name, (module, _help, _extra) in cli.COMMANDS.items():
        if importlib.util.find_spec(module) is None:
            continue  # not built yet: it is simply not listed
        mod = importlib.import_module(module)
        assert callable(getattr(mod, "add_arguments", None)), name
        assert callable(getattr(mod, "main", None)), name


def test_cli_import_is_light():
    code = "import sys, runtime.cli; print(sorted(m for m in ('sklearn', 'matplotlib', 'onnx') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "[]"


def test_bench_summary_names_every_benchmark():
    """`handover --help` is where a user first looks for what `handover bench` can run."""
    from trainer.commands.bench_cli import BENCHMARKS

    summary = cli.COMMANDS["bench"][1]
    assert [name for name in BENCHMARKS if name not in summary] == [], summary


def test_a_library_warning_is_one_line_naming_the_command(monkeypatch, tmp_path, capsys):
    import warnings

    monkeypatch.setattr(warnings, "formatwarning", warnings.formatwarning)  # restored after the test
    cli.main(["inspect", str(tmp_path / "none.onnx")])
    said = warnings.formatwarning("SVM search: 1 of 4 candidates stopped", UserWarning, "classifier.py", 198)
    assert said == "handover inspect: UserWarning: SVM search: 1 of 4 candidates stopped\n", said
    again = warnings.formatwarning("SVM search: 1 of 4 candidates stopped", UserWarning, "early.py", 140)
    assert again == "", "the same line from another place is said once"
