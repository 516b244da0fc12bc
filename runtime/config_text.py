"""deploy/handover.toml and docs/CONFIG.md, written from the declared keys (runtime/config_keys.py).

Both files are outputs of the one declaration, never edited by hand: ``python -m runtime.config_text``
rewrites them, and a test fails when either differs from what this module writes.
"""

from __future__ import annotations

import json
import sys
import textwrap
from pathlib import Path
from typing import Any

from runtime.config_keys import SECTIONS, Key, section_keys

__all__ = ["DEPLOY_FILE", "DOCS_FILE", "deploy_toml", "docs_markdown"]

ROOT = Path(__file__).resolve().parents[1]
DEPLOY_FILE = ROOT / "deploy" / "handover.toml"
DOCS_FILE = ROOT / "docs" / "CONFIG.md"
_WIDTH = 120
_COMMENT_AT = 41

_HEADER = """\
# handover daemon configuration (TOML). Every key is optional; the values shown are the defaults
# unless marked "example"; a commented key is unset (the model's recorded value, else the default shown).
# `handover run --config /etc/handover/handover.toml --check` validates it. After editing:
# `systemctl reload handover` (SIGHUP); an invalid file is refused and the running configuration stays.
# Written from runtime/config_keys.py by `python -m runtime.config_text`; docs/CONFIG.md explains every key.
"""


def toml_value(value: Any) -> str:
    """``value`` as TOML writes it."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, tuple | list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    return repr(value)


def _key_lines(k: Key) -> list[str]:
    help_text = k.help
    if k.optional and not k.shown:
        shown = k.example if k.example is not None else k.default
        line = f"# {k.short} = {toml_value(shown)}"
        if k.example is not None:
            help_text = "example; " + help_text
    else:
        value = k.example if k.shown else k.default
        line = f"{k.short} = {toml_value(value)}"
        if k.example is not None and not k.shown:
            help_text += f"; example: {toml_value(k.example)}"
    if k.choices and not all(c in help_text for c in k.choices):
        help_text += f" ({' | '.join(k.choices)})"
    if k.range is not None:
        help_text += f" [{_plain(k.range[0])},\0{_plain(k.range[1])}]"  # NUL: no line break inside the range
    pad = max(_COMMENT_AT, len(line) + 1)
    wrapped = [w.replace("\0", " ") for w in textwrap.wrap(help_text, _WIDTH - pad - 2)] or [""]
    lines = [f"{line.ljust(pad)}# {wrapped[0]}"]
    lines += [f"{'':{pad}}# {more}" for more in wrapped[1:]]
    return lines


def _plain(bound: float) -> str:
    return str(int(bound)) if float(bound).is_integer() else f"{bound:g}"


def deploy_toml() -> str:
    """The text of deploy/handover.toml."""
    out = [_HEADER]
    for section, note in SECTIONS.items():
        if section:
            out.append(f"\n[{section}]")
        out += [f"# {line}" for line in note.splitlines()]
        for k in section_keys(section):
            out += _key_lines(k)
    return "\n".join(out) + "\n"


def _md_value(value: Any) -> str:
    return "unset" if value is None else f"`{toml_value(value)}`"


def docs_markdown() -> str:
    """The text of docs/CONFIG.md."""
    out = ["# The daemon's configuration", "",
           "Every key of `handover run --config FILE` (TOML), written from their one declaration in",
           "`runtime/config_keys.py` by `python -m runtime.config_text` (a test keeps this page and",
           "`deploy/handover.toml` equal to it). Every key is optional. A wrong value stops the daemon at start",
           "with one line naming the key (`--check` validates a file; a SIGHUP with a wrong file keeps the",
           "running configuration). \"unset\" keys of `[trigger]` take the model's recorded setting, else the",
           "default shown."]
    for section, note in SECTIONS.items():
        out += ["", f"## `[{section}]`" if section else "## Top level", ""]
        if note:
            out += [" ".join(note.splitlines()), ""]
        out += ["| key | type | default | range | what it does |", "| --- | --- | --- | --- | --- |"]
        for k in section_keys(section, config_only=False):
            kind = "list of strings" if k.type is tuple else k.type.__name__
            limits = " \\| ".join(k.choices) if k.choices else (
                f"{_plain(k.range[0])} to {_plain(k.range[1])}" if k.range else "")
            default = _md_value(k.default) + (" (unset)" if k.optional and k.default is not None else "")
            help_text = k.help.replace("|", "\\|")
            if not k.config:
                help_text = "recorded by training only, not a config key: " + help_text
            elif k.recorded:
                help_text += " (unset: the model's recorded value)"
            if k.example is not None:
                help_text += f"; example: `{toml_value(k.example)}`"
            out.append(f"| `{k.short}` | {kind} | {default} | {limits} | {help_text} |")
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Rewrite both files (``--check``: only say which differ, exit 1 if any)."""
    check = "--check" in (argv if argv is not None else sys.argv[1:])
    stale = []
    for path, text in ((DEPLOY_FILE, deploy_toml()), (DOCS_FILE, docs_markdown())):
        current = path.read_text() if path.exists() else None
        if current != text:
            stale.append(path)
            if not check:
                path.write_text(text)
    for path in stale:
        print(f"{path}: {'differs from runtime/config_keys.py' if check else 'rewritten'}")
    return 1 if check and stale else 0


if __name__ == "__main__":
    sys.exit(main())
