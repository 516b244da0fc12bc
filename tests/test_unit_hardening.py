"""The systemd unit stays hardened: ``systemd-analyze security`` rates deploy/handover.service
at an exposure of 1.9 or lower (the level it had when issue 18 measured it). The tool comes with
systemd (Debian/Ubuntu: ``apt-get install systemd``); where it is absent the test skips and says so."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

UNIT = Path(__file__).resolve().parents[1] / "deploy" / "handover.service"
MAX_EXPOSURE = 1.9


def test_unit_exposure_is_at_most_1_9():
    tool = shutil.which("systemd-analyze")
    if tool is None:
        pytest.skip("systemd-analyze is not installed (apt-get install systemd); the unit's exposure is unchecked")
    proc = subprocess.run([tool, "security", "--offline=true", "--no-pager", str(UNIT)], capture_output=True,
                          text=True, timeout=120)
    if "--offline" in proc.stderr and "unrecognized" in proc.stderr:
        pytest.skip(f"this systemd-analyze has no --offline mode (systemd < 250): {proc.stderr.strip()[:120]}")
    found = re.search(r"Overall exposure level for handover\.service: (\d+(?:\.\d+)?)", proc.stdout)
    assert found, proc.stdout[-500:] + proc.stderr[-500:]
    exposure = float(found.group(1))
    print(f"\nsystemd-analyze security: exposure {exposure} (limit {MAX_EXPOSURE})")
    assert exposure <= MAX_EXPOSURE, [line for line in proc.stdout.splitlines() if line.startswith("✗")]
