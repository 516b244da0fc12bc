"""The installed package stands alone: no module of firmware_io, runtime or trainer imports the test
suite or the studies (neither is installed; such an import breaks in a wheel)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("firmware_io", "runtime", "trainer")
NOT_INSTALLED = ("tests", "studies")


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
    assert (ROOT / "studies" / "__init__.py").exists()


@pytest.mark.parametrize("package", PACKAGES)
def test_no_package_module_imports_tests_or_studies(package):
    offenders = [f"{path.relative_to(ROOT)} imports {sorted(imported_roots(path) & set(NOT_INSTALLED))}"
                 for path in sorted((ROOT / package).rglob("*.py")) if imported_roots(path) & set(NOT_INSTALLED)]
    assert not offenders, offenders


def test_the_check_finds_a_lazy_import(tmp_path):
    """The check sees an import inside a function, as trainer/bench/ros2.py had one."""
    module = tmp_path / "m.py"
    module.write_text("def f():\n    from tests.tiny_models import write_model\n    return write_model\n")
    assert "tests" in imported_roots(module)
