"""The one way a command reports a user error: ``handover CMD: message`` on stderr, an exit code."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from firmware_io.commands.errors import DEVICE_ERROR, USER_ERROR, fail

ROOT = Path(__file__).resolve().parents[1]


def test_fail_prints_one_line_and_returns_the_code(capsys):
    assert fail("dump", "--frames must be at least 1") == USER_ERROR == 2
    assert fail("record", "device lost", DEVICE_ERROR) == 1
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.splitlines() == ["handover dump: --frames must be at least 1", "handover record: device lost"]


def test_no_command_defines_its_own_fail():
    """Every command calls firmware_io.commands.errors.fail; a private copy would drift in format or code."""
    copies = [str(p.relative_to(ROOT)) for pkg in ("firmware_io", "runtime", "trainer")
              for p in (ROOT / pkg).rglob("*.py") if "def _fail(" in p.read_text()]
    assert copies == []


def test_a_command_error_through_the_entry_point():
    proc = subprocess.run([sys.executable, "-m", "runtime.cli", "dump", "sim://", "--frames", "0"], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and proc.stderr.strip() == "handover dump: --frames must be at least 1"
