"""The options every ``handover`` command shares, and argparse types that check a value as it is read.

One spelling and one message per option: ``--out``, ``--json``, ``--seed``, ``--quiet`` are added
here, and a range check is a ``type=`` so a wrong value is argparse's one line before any work.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import os
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

from firmware_io.errors import HandoverError
from firmware_io.trigger_level import PAPER_FRACTION, is_trigger_level

__all__ = ["PROGRESS", "add_json", "add_out", "add_quiet", "add_seed", "int_in", "out_folder", "positive_float",
           "positive_int", "progress_to", "settle_out_folders", "trigger_level"]

PROGRESS = logging.getLogger("handover.progress")
"""The one progress path of every command: plain lines on stderr (the daemon's log keeps its own format)."""


class _Stderr(logging.Handler):
    """stderr as it is when a line is written: a caller (a test, a notebook) may have swapped it since."""

    def emit(self, record: logging.LogRecord) -> None:
        print(self.format(record), file=sys.stderr, flush=True)


PROGRESS.addHandler(_Stderr())
PROGRESS.setLevel(logging.INFO)
PROGRESS.propagate = False


def add_out(parser: argparse.ArgumentParser, help: str, **kwargs) -> None:
    """``--out``: where the command writes (a folder or file, as ``help`` says)."""
    parser.add_argument("--out", help=help, **kwargs)


def add_json(parser: argparse.ArgumentParser, what: str = "the summary") -> None:
    """``--json``: the result as JSON on stdout, for a script to read."""
    parser.add_argument("--json", action="store_true", help=f"print {what} as JSON on stdout")


def add_seed(parser: argparse.ArgumentParser, default: int = 0, help: str = "random seed (same seed, same result)") -> None:
    """``--seed``: every random choice of the command follows from it."""
    parser.add_argument("--seed", type=int, default=default, help=help)


def add_lab(parser: argparse.ArgumentParser, what: str = "the simulated hand and people") -> None:
    """``--lab A|B``: which simulated lab (``firmware_io.sim.lab``) plays ``what``; an unknown one is one line."""
    parser.add_argument("--lab", type=lab_name, default="A", help=f"simulated lab of {what}: A (default) or B, "
                        "another hand and other people (docs/SIMULATOR.md)")


def lab_name(text: str) -> str:
    from firmware_io.sim.lab import UnknownLab, get_lab

    try:
        return get_lab(text).name
    except UnknownLab as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_quiet(parser: argparse.ArgumentParser, help: str = "no progress messages on stderr") -> None:
    """``--quiet``: the result only."""
    parser.add_argument("--quiet", action="store_true", help=help)


def progress_to(quiet: bool) -> Callable[[str], None]:
    """Where a command's progress lines go: the progress logger, or nowhere with ``--quiet``."""
    return (lambda _text: None) if quiet else PROGRESS.info


def positive_float(text: str) -> float:
    """A finite number above 0 (also refuses nan and inf, which compare false)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not 0 < value < math.inf:
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


def int_in(low: int, high: int | None = None) -> Callable[[str], int]:
    """A type for an integer in ``low..high`` (no upper bound when ``high`` is None)."""
    span = f"at least {low}" if high is None else f"in {low}..{high}"

    def read(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer {span}, got {text!r}") from None
        if value < low or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"must be {span}, got {value}")
        return value

    read.__name__ = "integer"  # argparse names the type in its message for an unparsable value
    return read


positive_int = int_in(1)
"""An integer of at least 1 (a count)."""


def trigger_level(text: str) -> float:
    """A threshold trigger's level (``--fraction``): a fraction of full scale strictly between 0 and 1."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not is_trigger_level(value):
        raise argparse.ArgumentTypeError(f"must be a fraction of full scale in (0, 1), e.g. {PAPER_FRACTION}, got {text!r}")
    return value


_MADE: list[Path] = []
"""Folders ``out_folder`` created in this process, the deepest first (``settle_out_folders``)."""


def settle_out_folders(failed: bool) -> None:
    """At a command's end: if it ``failed``, remove the folders ``out_folder`` created that are still empty
    (no empty ``--out`` left behind; one with files in it stays); either way forget them."""
    while _MADE:
        made = _MADE.pop(0)
        if failed:
            with contextlib.suppress(OSError):
                made.rmdir()


def _to_make(path: Path) -> list[Path]:
    """The folders ``path.mkdir(parents=True)`` will create, resolved and the deepest first: in
    ``new/../old`` only ``new`` (``old`` was there before and must outlive a failed command)."""
    real = [Path(os.path.realpath(Path(*path.parts[:i]))) for i in range(1, len(path.parts) + 1)]
    return list(dict.fromkeys(p for p in reversed(real) if not p.exists()))


def out_folder(folder: str | Path, option: str = "--out") -> Path:
    """Create ``folder`` (and its parents) and check it takes files, before any work; HandoverError if not."""
    if not str(folder).strip():  # Path("") is the current folder: an empty option is a slip, not a choice
        raise HandoverError(f"{option} is empty; give a folder (it is created if missing), e.g. {option} ./out")
    path = Path(folder)
    blocker = next((p for p in (path, *path.parents) if p.exists()), None)
    if blocker is not None and not blocker.is_dir():  # the folder itself or one it would be made in
        raise HandoverError(f"{option} {path}: {blocker} is a file, not a folder; choose a folder (it is created if "
                            "missing)")
    try:
        missing = _to_make(path)
        path.mkdir(parents=True, exist_ok=True)
        _MADE.extend(missing)
        with tempfile.NamedTemporaryFile(dir=path, prefix=".write-test-"):
            pass
    except OSError as exc:
        reason = exc.strerror or str(exc)
        raise HandoverError(f"{option} {path}: cannot create or write this folder ({reason}); choose a folder you can "
                            f"write (it is created if missing), e.g. {option} ./out") from None
    return path
