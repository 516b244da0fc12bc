"""The code base stays ruff-clean (configuration in pyproject.toml)."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_ruff_clean():
    ruff = shutil.which("ruff") or str(Path(sys.executable).with_name("ruff"))
    if not Path(ruff).exists():
        pytest.skip("ruff is not installed (it comes with the dev extra)")
    result = subprocess.run([ruff, "check", "--no-cache", "."], cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


ISSUE_NUMBER = re.compile(r"#\d+|\b[Ii]ssues? #?\d+")
"""``#16``, ``issue 13``, ``issues #12``: an issue number (what a reader cannot look up in the code)."""


def test_no_issue_numbers_in_the_packages():
    """Docstrings and comments say why, not which issue asked for it (the tracker is not shipped)."""
    found = [f"{path.relative_to(ROOT)}:{n}: {line.strip()}"
             for package in ("firmware_io", "runtime", "trainer") for path in sorted((ROOT / package).rglob("*.py"))
             for n, line in enumerate(path.read_text().splitlines(), 1) if ISSUE_NUMBER.search(line)]
    assert not found, "\n".join(found)


def test_the_issue_number_check_sees_them():
    assert all(ISSUE_NUMBER.search(s) for s in ("(issue #16)", "issue 13", "see #19", "Issues 12"))
    assert not any(ISSUE_NUMBER.search(s) for s in ("pad 3", "# comment", "[#] x", "tissue 3"))


def test_the_readme_is_read_in_five_minutes():
    """At most 150 lines: what it is, the two commands, the daemon without a hand, from a real hand to a
    service, one results table, links; everything else lives in docs/ (docs/GUIDE.md)."""
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= 150, f"README.md has {len(lines)} lines; move details to docs/GUIDE.md"
    for target in ("docs/GUIDE.md", "docs/CONFIG.md", "docs/INTERFACES.md", "deploy/INSTALL.md"):
        assert (ROOT / target).exists() and target in "\n".join(lines), target


def test_nothing_points_outside_the_repository():
    """The design, the protocol and the docs a stranger reads are in the repository; only the real
    recordings are read from ``../shared/data`` (skipped where absent)."""
    outside = re.compile(r"\.\./shared/(?!data\b)")
    found = [f"{path.relative_to(ROOT)}:{n}" for path in sorted(ROOT.rglob("*"))
             if path.suffix in (".py", ".md", ".toml") and not {".venv", ".git"} & set(path.relative_to(ROOT).parts)
             for n, line in enumerate(path.read_text().splitlines(), 1) if outside.search(line)]
    assert not found, found


def test_the_terms_of_the_readmes_results_are_explained_in_the_glossary():
    readme, design = (ROOT / "README.md").read_text(), (ROOT / "docs" / "DESIGN.md").read_text()
    glossary = design[design.index("## Glossary"):]
    for term in ("onset_dormant", "leave-one-subject-out", "TEASER", "ProbabilityThreshold",
                 "harmonic mean of accuracy and earliness", "MiniRocket", "F1", "p99.9", "synthetic"):
        assert term in " ".join(glossary.split()), term
    assert "docs/DESIGN.md#glossary" in readme
