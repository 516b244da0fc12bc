"""Layers one way: firmware_io imports nothing from runtime or trainer, runtime nothing from trainer, and no
module of the three imports the test suite or the benchmarks (neither is installed; such an import breaks in a
wheel). A new rule is one line of FORBIDDEN."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NOT_INSTALLED = {"tests", "benchmarks"}
FORBIDDEN: dict[str, set[str]] = {
    "firmware_io": NOT_INSTALLED | {"runtime", "trainer"},  # trainer -> runtime -> firmware_io, never upwards
    "runtime": NOT_INSTALLED | {"trainer"},
    "trainer": NOT_INSTALLED,
}
"""package -> the top-level names none of its modules may import."""


def imported_roots(path: Path) -> set[str]:
    """Top-level names of every module ``path`` imports (at any depth: lazy imports count too)."""
    roots = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            roots |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            roots.add(node.module.split(".")[0])
    return roots


def test_the_installed_packages_are_what_pyproject_installs():
    text = (ROOT / "pyproject.toml").read_text()
    assert 'include = ["firmware_io*", "runtime*", "trainer*"]' in text
    assert all((ROOT / name / "__init__.py").exists() for name in NOT_INSTALLED - {"tests"})


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_no_package_module_imports_what_its_layer_forbids(package):
    offenders = [f"{path.relative_to(ROOT)} imports {sorted(imported_roots(path) & FORBIDDEN[package])}"
                 for path in sorted((ROOT / package).rglob("*.py")) if imported_roots(path) & FORBIDDEN[package]]
    assert not offenders, offenders


def test_the_check_finds_a_lazy_import(tmp_path):
    """The check sees an import inside a function, as a benchmark once had one."""
    module = tmp_path / "m.py"
    module.write_text("def f():\n    from benchmarks.streams import real_files\n    return real_files\n")
    assert "benchmarks" in imported_roots(module)
