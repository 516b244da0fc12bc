"""The ``handover`` command: one entry point, subcommands imported only when chosen.

Each subcommand lives in its own module with ``add_arguments(parser)`` and
``main(args) -> int``. Only the chosen module is imported, so ``handover run`` never
pulls in scikit-learn or matplotlib.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import os
import sys
from collections.abc import Sequence
from typing import NoReturn

from firmware_io.commands.options import settle_out_folders
from firmware_io.errors import HandoverError

__all__ = ["COMMANDS", "HelpFormatter", "OneLineParser", "build_parser", "main", "shows_default"]

# name -> (module, one-line help, extra it needs beyond the daemon's install or None)
COMMANDS: dict[str, tuple[str, str, str | None]] = {
    "demo": ("trainer.commands.demo_cli", "end-to-end demo on the simulated hand: simulate, train, export, emulate, detect", "train"),
    "simulate": ("firmware_io.commands.simulate_cli", "write the paper's protocol (or a scripted session) from the simulated hand", None),
    "import": ("firmware_io.commands.import_cli", "convert DSA-Konqueror .dsa files or ROS bags (bags need [train]) to recordings", None),
    "train": ("trainer.commands.train_cli", "train the default features (or BoW, the paper's) + SVM, evaluate as in the paper, write a report and the ONNX model", "train"),
    "sweep": ("trainer.commands.sweep_cli", "accuracy against K, W, T and kernel (the paper's sweeps)", "train"),
    "export": ("trainer.commands.export_cli", "export a trained model to one ONNX graph", "train"),
    "verify": ("trainer.commands.verify_cli", "compare an ONNX model with the float64 reference, with stress cases", "train"),
    "inspect": ("runtime.commands.inspect_cli", "print a model card from an ONNX model's metadata", None),
    "emulate": ("firmware_io.commands.emulate_cli", "serve an emulated DSACON32m over TCP or a pseudo-terminal (the demo's unseen session by default)", None),
    "score": ("trainer.commands.score_cli", "score a captured event stream against handover emulate --script-out (the demo's summary)", None),
    "dump": ("firmware_io.commands.dump_cli", "print frames from any device URL (rate, per-pad sums, errors)", None),
    "run": ("runtime.commands.daemon_cli", "the detection daemon (systemd service)", None),
    "review": ("trainer.commands.review_cli", "label a daemon's captured events, one keystroke each (labels.json beside the capture)", None),
    "record": ("trainer.commands.record_cli", "record a subject session following the paper's protocol", None),
    "plot": ("trainer.commands.plot_cli", "plot a trial of a recording", "train"),
    "bench": ("trainer.commands.bench_cli", "measure this machine: latency, throughput, inference (the studies behind results/ are a checkout's ./dev bench)", "train"),
}

EXTRA_PACKAGES: dict[str, tuple[str, ...]] = {
    "train": ("sklearn", "onnx", "matplotlib", "tqdm", "joblib"),
    "usb": ("usb", "hid"),
    "bench": ("aeon",),
}
"""The import names each extra of pyproject.toml brings (rosbags, also in [train], only for bags)."""
OWN_PACKAGES = ("firmware_io", "runtime", "trainer")
_PACKAGE_EXTRA = {pkg: extra for extra, pkgs in EXTRA_PACKAGES.items() for pkg in pkgs} | {"rosbags": "train"}


def install_hint(extra: str) -> str:
    """The one way to get an extra, said the same way everywhere."""
    return f"install it with: pip install 'tactile-handover[{extra}]'"


def missing_packages(extra: str | None) -> list[str]:
    if extra is None:
        return []
    return [pkg for pkg in EXTRA_PACKAGES[extra] if importlib.util.find_spec(pkg) is None]


def shows_default(action: argparse.Action) -> bool:
    """An option whose default is worth showing (not None, not an off flag; 0 is a default)."""
    default = action.default
    return bool(action.option_strings) and not (
        default is None or default is False or default == argparse.SUPPRESS
        or isinstance(action, argparse.BooleanOptionalAction))  # that one says its default itself


class HelpFormatter(argparse.HelpFormatter):
    """Every command's ``--help`` shows each option's default (unless the text already says it,
    or there is none to show): one place for all commands."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if "default" in text.lower() or not shows_default(action):
            return text
        return f"{text} (default: %(default)s)"


class OneLineParser(argparse.ArgumentParser):
    """A wrong option is one line that says where the options are, not argparse's usage block."""

    def error(self, message: str) -> NoReturn:  # argparse calls it for every wrong option
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")

    def parse_known_args(self, args: Sequence[str] | None = None,
                         namespace: argparse.Namespace | None = None) -> tuple[argparse.Namespace, list[str]]:
        """Also refuses an empty value (``--out ''``, ``--data=``): a slip, and an empty path means the
        current folder, where the command would write its outputs. Options whose default
        is the empty string (``--fault ''``: no faults) take it."""
        args = list(sys.argv[1:] if args is None else args)
        for i, arg in enumerate(args):
            name, eq, value = arg.partition("=")
            if name.startswith("--") and eq and not value.strip() and not self._empty_allowed(name):
                self.error(f"{name} is empty; give it a value")
            before = args[i - 1] if i and args[i - 1].startswith("-") else ""
            if not arg.strip() and not self._empty_allowed(before):
                self.error(f"{before or 'an argument'} is empty; give it a value")
        return super().parse_known_args(args, namespace)

    def _empty_allowed(self, option: str) -> bool:
        action = self._option_string_actions.get(option)
        return action is not None and action.default == ""


def build_parser(name: str, module) -> argparse.ArgumentParser:
    """The parser of one command, its --help showing every default (also of options without a help text)."""
    parser = OneLineParser(prog=f"handover {name}", description=COMMANDS[name][1], formatter_class=HelpFormatter)
    module.add_arguments(parser)
    for action in parser._actions:
        if not action.help and shows_default(action):
            action.help = "(default: %(default)s)"
    return parser


def _usage() -> str:
    width = max(len(n) for n in COMMANDS)
    lines = ["usage: handover COMMAND [options]", "", "commands:"]
    for name, (_module, help_text, extra) in COMMANDS.items():
        need = f"  [needs tactile-handover[{extra}]]" if extra else ""
        lines.append(f"  {name:<{width}}  {help_text}{need}")
    lean = ", ".join(n for n, (_m, _h, extra) in COMMANDS.items() if extra is None)
    lines += ["", "Commands marked [needs ...] run only with that extra installed; the daemon's own install",
              f"(pip install tactile-handover) runs {lean}.", "", "handover COMMAND --help shows the options of one command."]
    return "\n".join(lines)


def _missing_module_line(name: str, exc: ModuleNotFoundError) -> str:
    missing = (exc.name or "?").split(".")[0]
    extra = _PACKAGE_EXTRA.get(missing)
    hint = f"; {install_hint(extra)}" if extra else ""
    return f"handover {name}: needs the Python package {missing!r}, which is not installed{hint}"


def _one_line_warnings(name: str) -> None:
    """A library's warning on the console is one line that names the command, not Python's two (the
    message and a source line a user cannot act on); said once per command, however many places raise it
    (two capped SVM fits printed the same line twice)."""
    import warnings

    said: set[str] = set()

    def one_line(message, category, *_args, **_kwargs) -> str:
        line = f"handover {name}: {category.__name__}: {message}\n"
        if line in said:
            return ""
        said.add(line)
        return line

    warnings.formatwarning = one_line


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(_usage())
        return 0
    if argv[0] == "--version":
        from runtime import __version__

        print(__version__)
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        import difflib

        close = difflib.get_close_matches(name, COMMANDS, n=1)
        hint = f"did you mean 'handover {close[0]}'? " if close else ""
        print(f"handover: unknown command {name!r}; {hint}'handover --help' lists the commands", file=sys.stderr)
        return 2
    module_name, _help, extra = COMMANDS[name]
    _one_line_warnings(name)
    if missing := missing_packages(extra):
        print(f"handover {name}: needs the extra [{extra}] (missing: {', '.join(missing)}); {install_hint(extra)}",
              file=sys.stderr)
        return 2
    code = 1
    try:
        module = importlib.import_module(module_name)
        args = build_parser(name, module).parse_args(rest)
        code = int(module.main(args) or 0)
        return code
    except ModuleNotFoundError as exc:  # a package imported only when the command needs it
        if (exc.name or "").split(".")[0] in OWN_PACKAGES:
            raise  # a broken checkout, not a missing extra
        print(_missing_module_line(name, exc), file=sys.stderr)
        return 2
    except HandoverError as exc:  # the one place an error of the three packages becomes a line and a code
        print(f"handover {name}: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"handover {name}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `handover dump sim:// | head`: the reader has seen enough
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        code = 0
        return 0
    finally:
        settle_out_folders(failed=code != 0)


if __name__ == "__main__":
    sys.exit(main())
