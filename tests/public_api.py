"""The public names of every module (its ``__all__``), as docs/INTERFACES.md lists them.

``python -m tests.public_api`` rewrites that list in docs/INTERFACES.md (between the markers);
tests/test_public_api.py fails when the list and the modules differ.
"""

from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
INTERFACES = ROOT / "docs" / "INTERFACES.md"
PACKAGES = ("firmware_io", "runtime", "trainer")
BEGIN = "<!-- public names: written by `python -m tests.public_api` from each module's __all__ -->"
END = "<!-- /public names -->"


def stated_modules() -> list[Path]:
    """Modules that state their public names: every module of the packages except the benchmark
    command's parts (trainer/bench/, reached through ``handover bench`` only)."""
    return [p for pkg in PACKAGES for p in sorted((ROOT / pkg).rglob("*.py")) if p.parent != ROOT / "trainer" / "bench"]


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def declared_all(path: Path) -> list[str] | None:
    """The module's ``__all__`` (a literal list), or None without one."""
    for node in ast.parse(path.read_text()).body:
        target = node.targets[0] if isinstance(node, ast.Assign) else getattr(node, "target", None)
        if isinstance(target, ast.Name) and target.id == "__all__" and getattr(node, "value", None) is not None:
            return [ast.literal_eval(e) for e in node.value.elts]
    return None


def _code_texts() -> dict[Path, str]:
    return {p: p.read_text() for p in ROOT.rglob("*.py") if not {".venv", ".git"} & set(p.relative_to(ROOT).parts)}


def unused_names() -> dict[str, list[str]]:
    """Per module, the names of its ``__all__`` that no other file naming the module mentions
    (``a.b.c``, ``from a.b import c``, ``from .c import``): the list says what other modules use."""
    texts = _code_texts()
    found = {}
    for path in stated_modules():
        module = module_name(path)
        parent, _, leaf = module.rpartition(".")
        naming = re.compile(rf"{re.escape(module)}\b|from {re.escape(parent)} import [^\n]*\b{leaf}\b|from \.{leaf} import")
        users = [t for p, t in texts.items() if p != path and naming.search(t)]
        unused = [n for n in declared_all(path) or [] if not any(re.search(rf"\b{re.escape(n)}\b", t) for t in users)]
        if unused:
            found[module] = unused
    return found


def listing() -> str:
    """The section of docs/INTERFACES.md: one line a module that exports names."""
    lines = [BEGIN, "## Public names of every module", "",
             "Each module's `__all__`: the names other modules use (the rest are its own details; a package",
             "whose list is empty exports its modules only; tests/test_public_api.py keeps the lists so). The benchmarks' parts (trainer/bench/)",
             "are reached through `handover bench` and state none.", ""]
    for path in stated_modules():
        names = declared_all(path)
        if names:
            lines.append(f"- `{module_name(path)}`: " + ", ".join(f"`{n}`" for n in names))
    return "\n".join([*lines, END])


def current_section() -> str | None:
    text = INTERFACES.read_text()
    if BEGIN not in text or END not in text:
        return None
    return text[text.index(BEGIN): text.index(END) + len(END)]


def main() -> int:
    text = INTERFACES.read_text()
    section = current_section()
    text = text.replace(section, listing()) if section else text.rstrip("\n") + "\n\n" + listing() + "\n"
    INTERFACES.write_text(text)
    print(f"{INTERFACES}: public names written")
    return 0


if __name__ == "__main__":
    sys.exit(main())
