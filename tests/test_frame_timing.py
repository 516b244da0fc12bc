"""The frame rate has owners: the controller's nominal rate in ``firmware_io.frame_timing``, the
measured mean interval of the real recordings in ``firmware_io.sim.constants``. No other module of
the packages or the benchmarks restates either as a number (it was written as 32.0, 1 / 32, 31.25 ms,
1e6 / 32.0 and 0.03156 in a dozen places, two of them a different quantity under the same name)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from firmware_io.frame_timing import NOMINAL_PERIOD_S, NOMINAL_RATE_HZ, nominal_stamp_ms
from firmware_io.sim import constants as K

ROOT = Path(__file__).resolve().parents[1]
OWNERS = {"firmware_io/frame_timing.py", "firmware_io/sim/constants.py"}
RATE_NUMBERS = {32.0, 31.25, 0.03125, 0.03156, 31.56, 0.0316}
"""The rate, the period (s, ms) at the nominal rate and the measured mean interval, as literals."""
NOT_A_RATE = {
    ("firmware_io/layout.py", 32.0): "pad centres in mm",
    ("firmware_io/sim/actions.py", 32.0): "a push depth in mm",
    ("benchmarks/studies/realism_plot.py", 0.0316): "the committed realism figure's time axis, kept as it was drawn",
}


def rate_literals(text: str, rel: str) -> list[str]:
    """Float literals equal to a rate number, and any division by 32 (``1 / 32``, ``n / 32``)."""
    found = []
    for node in ast.walk(ast.parse(text, rel)):
        if isinstance(node, ast.Constant) and type(node.value) is float and node.value in RATE_NUMBERS:
            found.append((node.lineno, node.value))
        elif (isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div) and isinstance(node.right, ast.Constant)
              and node.right.value == 32):
            found.append((node.lineno, 32))
    return [f"{rel}:{line} {value}" for line, value in found if (rel, value) not in NOT_A_RATE]


@pytest.mark.parametrize("package", ["firmware_io", "runtime", "trainer", "benchmarks"])
def test_no_module_restates_the_frame_rate(package):
    files = {str(p.relative_to(ROOT)): p for p in sorted((ROOT / package).rglob("*.py"))}
    assert files, f"{package}/ holds no module: a moved folder must be named here"
    stray = [hit for rel, path in files.items() if rel not in OWNERS for hit in rate_literals(path.read_text(), rel)]
    assert not stray, f"import the rate from firmware_io.frame_timing or firmware_io.sim.constants: {stray}"


def test_the_check_finds_each_way_the_rate_was_written():
    text = "a = 1 / 32\nb = 1e6 / 32.0\nc = round(7 * 31.25)\nd = 0.03156\ne = 32\n"
    assert sorted(h.split()[1] for h in rate_literals(text, "trainer/x.py")) == ["0.03156", "31.25", "32", "32", "32.0"]
    assert rate_literals("depth = 32.0\n", "firmware_io/sim/actions.py") == []


def test_the_two_quantities_are_two_and_the_stamps_keep_their_values():
    """Nominal and measured differ (the PC reads some frames late); a frame's stamp is the
    millisecond the benches always gave it."""
    assert NOMINAL_PERIOD_S == 1 / NOMINAL_RATE_HZ and K.FRAME_PERIOD_S > NOMINAL_PERIOD_S
    assert [nominal_stamp_ms(i) for i in (0, 1, 2, 3, 1000)] == [round(i * 31.25) for i in (0, 1, 2, 3, 1000)]
