"""The soak benchmark: its bookkeeping on hand-made logs (fast) and a short real run (slow).

The real run is the benchmark itself, shortened: the daemon in its own process against the
emulator with every fault kind injected; speed is not asserted, losses and recoveries are."""

from __future__ import annotations

import json

import pytest

from benchmarks import soak_account as A
from benchmarks.soak import Fault, Plan
from benchmarks.soak_rig import watchdog_gaps


def test_watchdog_gaps_count_only_silences_longer_than_the_limit():
    pings = [1.0, 6.0, 11.0, 30.0, 35.0]
    assert watchdog_gaps(pings, 0.0, 40.0, 10.0) == [(11.0, 30.0)]
    assert watchdog_gaps([], 0.0, 5.0, 10.0) == []


def test_a_loss_inside_a_fault_is_the_faults_and_outside_is_not():
    sent = [(k * 31, 100.0 + k / 32) for k in range(640)]  # 20 s of frames
    lost = {256, 257, 258, 500}  # three in the fault at 8 s, one at 15.6 s with no fault
    received = {s: t + 0.001 for s, t in sent if sent.index((s, t)) not in lost}
    fault = Fault("disconnect", start=100.0 + 256 / 32, end=100.0 + 256 / 32)
    windows = A.fault_windows([fault], sent, received)
    assert fault.recovered_at is not None and fault.recovered_at - fault.end < 0.2
    figures = A.frame_figures(sent, received, windows, t0=100.0, t_end=120.0)
    assert figures["frames_lost_inside_injected_faults"] == 3
    assert figures["frames_lost_outside_injected_faults"] == 1


def test_an_expected_event_missing_is_lost():
    sent = [(k * 31, 10.0 + k / 32) for k in range(1000)]
    received = {s: t for s, t in sent}
    reference = {300, 700}
    events = [(0.0, {"device_time_ms": 300 * 31})]
    figures = A.event_figures(sent, received, [], events, reference, 1000, t0=10.0, t_end=50.0, history=128)
    assert figures["events_expected"] == 2 and figures["events_lost"] == 1


def test_the_plan_scales_to_the_run():
    hour = Plan.for_hours(1.0)
    assert hour.fault_every == 60.0 and hour.hangs
    assert not Plan.for_hours(0.01).hangs


@pytest.mark.slow
def test_soak_smoke(tmp_path):
    """72 s of soak with every fault kind but hangs: nothing lost outside a fault, every
    fault recovered, the watchdog never silent while healthy, the files written."""
    from benchmarks.__main__ import main as bench

    assert bench(["soak", "--hours", "0.02", "--out", str(tmp_path), "--quiet"]) == 0
    r = json.loads((tmp_path / "soak.json").read_text())
    for key in ("hours", "frames_expected", "frames_lost_outside_injected_faults", "faults_injected",
                "faults_recovered", "max_recovery_s", "events_lost", "rss_growth_mb", "watchdog_would_fire",
                "hostile_inputs"):
        assert key in r, key
    assert r["frames_expected"] > 1000
    assert r["frames_lost_outside_injected_faults"] == 0, r["lost_outside_examples"]
    assert r["faults_injected"] >= 7 and r["faults_recovered"] == r["faults_injected"], r["fault_log"]
    assert r["events_lost"] == 0, r["events_lost_at_s"]
    assert r["watchdog_would_fire_while_healthy"] == 0
    assert r["daemon_log"]["tracebacks"] == 0
    assert (tmp_path / "soak.md").read_text().startswith("# Soak")
