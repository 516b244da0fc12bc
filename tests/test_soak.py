"""The soak benchmark: its bookkeeping on hand-made logs (fast) and a short real run (slow).

The real run is the benchmark itself, shortened: the daemon in its own process against the
emulator with every fault kind injected; speed is not asserted, losses and recoveries are."""

from __future__ import annotations

import json

import pytest

from benchmarks import soak_account as A
from benchmarks.soak import Fault, Plan
from benchmarks.soak_rig import ScheduledEmulator, watchdog_gaps


def test_watchdog_gaps_count_only_silences_longer_than_the_limit():
    pings = [1.0, 6.0, 11.0, 30.0, 35.0]
    assert watchdog_gaps(pings, 0.0, 40.0, 10.0) == [(11.0, 30.0)]
    assert watchdog_gaps([], 0.0, 5.0, 10.0) == []


def test_a_loss_inside_a_fault_is_the_faults_and_outside_is_not():
    sent = [(k * 31, 100.0 + k / 32, k) for k in range(640)]  # 20 s of frames
    lost = {256, 257, 258, 500}  # three in the fault at 8 s, one at 15.6 s with no fault
    handled = A.which_sent(sent, [s for k, (s, _, _) in enumerate(sent) if k not in lost],
                           [t + 0.001 for k, (_, t, _) in enumerate(sent) if k not in lost])
    fault = Fault("disconnect", start=100.0 + 256 / 32, end=100.0 + 256 / 32)
    windows = A.fault_windows([fault], sent, handled)
    assert fault.recovered_at is not None and fault.recovered_at - fault.end < 0.2
    figures = A.frame_figures(sent, handled, windows, t0=100.0, t_end=120.0)
    assert figures["frames_lost_inside_injected_faults"] == 3
    assert figures["frames_lost_outside_injected_faults"] == 1


def test_a_stamp_that_recurs_after_a_power_cycle_names_the_frame_sent_last_before_it_arrived():
    """A power-cycled controller restarts its clock: the stamps of the first 10 s come again after
    the boot. Keyed by stamp alone, the frames after the unplug were the ones before it (handled,
    recovered before the fault) or none at all."""
    before = [(k * 31, 100.0 + k / 32, k) for k in range(320)]  # 10 s, then unplugged
    after = [(k * 31, 119.0 + k / 32, 608 + k) for k in range(320)]  # the clock from 0 again after the boot
    sent = before + after
    stamps = [s for s, _, _ in sent]
    handled = A.which_sent(sent, stamps, [t + 0.002 for _, t, _ in sent])
    assert handled == {k: t + 0.002 for k, (_, t, _) in enumerate(sent)}
    fault = Fault("disconnect", start=110.0, end=110.0)
    A.fault_windows([fault], sent, handled)
    assert fault.recovered_at == 119.002
    only_after = A.which_sent(sent, stamps[320:], [t + 0.002 for _, t, _ in after])
    assert sorted(only_after) == list(range(320, 640))


def test_an_expected_event_missing_is_lost():
    """The reference names recording frames: a sent frame's is its sequence number, which runs ahead
    of its place in the log by the frames skipped while the daemon was away."""
    skipped = 150
    sent = [(k * 31, 10.0 + k / 32, k + skipped) for k in range(1000)]
    handled = {k: t for k, (_, t, _) in enumerate(sent)}
    reference = {300 + skipped, 700 + skipped}  # sent as the 300th and 700th frame
    events = [(sent[300][1] + 0.01, {"device_time_ms": 300 * 31})]
    figures = A.event_figures(sent, handled, [], events, reference, 2000, t0=10.0, t_end=50.0, history=128)
    assert figures["events_expected"] == 2 and figures["events_lost"] == 1
    assert figures["events_lost_at_s"] == [round(700 / 32, 2)] and figures["events_outside_reference"] == 0


def test_the_rig_logs_the_stamps_that_go_on_the_wire_across_a_power_cycle():
    """Every TCP drop power-cycles the emulated controller, whose clock then restarts; the log of
    what was sent must carry the stamps the daemon sees (it once counted from the first power-on)."""
    emu, clock = _scheduled()
    wire = _pushed_stamps(emu, clock, 1.0)
    emu.power_cycle()  # what the TCP server does when the host's connection ends
    clock.t += 8.5  # the boot
    wire += _pushed_stamps(emu, clock, 1.0)
    assert len(wire) > 50 and wire == [s for s, _, _ in emu.sent]
    assert [q for _, _, q in emu.sent] == sorted({q for _, _, q in emu.sent})


@pytest.mark.parametrize("kind, count", [("crc", "crc_corrupted"), ("garbage", "garbage_inserted"),
                                         ("drop", "packets_truncated")])
def test_a_burst_damages_the_next_frames_and_ends(kind, count):
    emu, clock = _scheduled()
    _pushed_stamps(emu, clock, 0.2)
    emu.burst(kind, 4)
    _pushed_stamps(emu, clock, 0.5)
    assert getattr(emu.stats, count) == 4 and not emu.burst_active()


def _scheduled():
    from firmware_io.emulator.frame_source import placeholder_session
    from tests.clocks import ManualClock

    clock = ManualClock(100.0)
    emu = ScheduledEmulator(placeholder_session(seed=1, events=1), clock=clock, speed=1.0)
    emu.connect()
    return emu, clock


def _pushed_stamps(emu, clock, seconds: float) -> list[int]:
    """Push mode started, then the device stamps of the whole frames read over ``seconds``."""
    from firmware_io.wire import requests
    from firmware_io.wire.frames import decode_frame_payload
    from firmware_io.wire.parser import StreamParser

    emu.feed(requests.push_request())
    parser, stamps, end = StreamParser(emu.layout.n_taxels), [], clock.t + seconds
    while clock.t < end:
        clock.t += 0.01
        for p in parser.feed(emu.read(1 << 20)):
            if p.packet_id == 0:
                stamps.append(decode_frame_payload(p.payload, emu.layout.n_taxels)[0])
    return stamps


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
