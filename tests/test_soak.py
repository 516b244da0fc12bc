"""The soak benchmark: its bookkeeping on hand-made logs (fast) and a short real run (slow).

The real run is the benchmark itself, shortened: the daemon in its own process against the
emulator with every fault kind injected; speed is not asserted, losses and recoveries are."""

from __future__ import annotations

import json
import os
import time

import pytest

from benchmarks import soak_account as A
from benchmarks import soak_schedule as S
from benchmarks.soak_rig import ScheduledEmulator, watchdog_gaps
from benchmarks.soak_schedule import Fault, Plan, Schedule
from tests.clocks import ManualClock

SMOKE_HOURS = 0.033
"""The slow smoke's length (118.8 s): room for one fault of every kind but hangs, each after the
last has recovered (test_the_smoke_schedule_...), and no hangs (those need two minutes)."""


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


def test_a_fault_waits_until_the_last_recovered_and_the_daemon_streamed_clean():
    """The emulated controller boots for 8 s after every TCP close: a fault due by the cadence alone
    would land inside the last one's outage (6 s apart, the smoke's faults overlapped)."""
    clock = ManualClock(100.0)
    schedule = Schedule(Plan.for_hours(SMOKE_HOURS), clock)
    clock.t += 3.0
    assert schedule.due() == ("fault", "disconnect")
    schedule.injected(Fault("disconnect", start=clock.t, end=clock.t))
    clock.t += 7.0  # past fault_every (6 s), the controller still booting
    assert _faults_due(schedule) == []
    schedule.handled(102.9, 112.0)  # a frame sent before the fault, handled late: no recovery
    clock.t = 112.0
    assert _faults_due(schedule) == []
    for k in range(int(S.CLEAN_AFTER_FAULT_S * 32)):  # recovered at 112.0, then streaming
        schedule.handled(111.99 + k / 32, 112.0 + k / 32)
    clock.t = 112.0 + S.CLEAN_AFTER_FAULT_S
    assert _faults_due(schedule) == []  # one frame short of the clean stretch
    schedule.handled(111.99 + S.CLEAN_AFTER_FAULT_S + 0.02, clock.t)
    assert _faults_due(schedule) == ["stall_short"]


def test_a_fault_never_recovered_holds_the_schedule_only_as_long_as_the_accounting_waits():
    clock = ManualClock(0.0)
    schedule = Schedule(Plan.for_hours(1.0), clock)
    clock.t = 30.0
    schedule.injected(Fault("stall_long", start=30.0, end=33.0))
    clock.t = 33.0 + A.RECOVERY_LIMIT_S
    assert _faults_due(schedule) == []
    clock.t += 0.1
    assert _faults_due(schedule) == ["stall_short"]


def test_the_smoke_schedule_fits_every_kind_with_frames_and_events_to_check():
    """The smoke's schedule played on a manual clock against a model of the daemon (the outages
    the slow smoke measured): every kind but hangs is injected, more than 1000 frames are
    expected, and after every fault some frames have the clean history an event needs. With faults
    by the cadence alone (the old schedule) they overlap: about 20 s streamed, no event checkable."""
    clock = ManualClock(50.0)
    plan = Plan.for_hours(SMOKE_HOURS)
    schedule, faults, sent, handled, slots = Schedule(plan, clock), [], [], {}, 0
    while clock.t < schedule.t0 + plan.seconds:
        clock.t = round(clock.t + 0.2, 6)
        while (t := schedule.t0 + 1.0 + slots / 32) <= clock.t:  # the first connect takes 1 s
            _model_frame(t, faults, sent, handled, schedule)
            slots += 1
        action, kind = schedule.due() or ("", "")
        if action == "fault":
            duration, _ = OUTAGES[kind]
            faults.append(Fault(kind, start=clock.t, end=clock.t + duration))
            if kind in ("crc", "garbage_burst", "drop"):
                clock.t += duration  # inject returns once the burst is over
            schedule.injected(faults[-1])
    windows = A.fault_windows(faults, sent, handled)
    t0, t_end = schedule.t0, schedule.t0 + plan.seconds
    assert [f.kind for f in faults] == [k for k in S.FAULT_KINDS if k != "hang"]
    assert all(f.recovered_at is not None for f in faults)
    assert A.frame_figures(sent, handled, windows, t0, t_end)["frames_expected"] > 1000
    history = int(S.CLEAN_HISTORY_S * 32)
    for f, after in zip(faults, [*faults[1:], None], strict=True):  # every sent frame a reference decision
        until = after.start if after else t_end - 2.0
        eligible = A.event_figures(sent, handled, windows, [], set(range(len(sent))), len(sent),
                                   f.recovered_at - A.SETTLE_S, until + 2.0, history)["events_expected"]
        assert eligible >= 32, (f.kind, eligible)  # a second of frames an event could end


OUTAGES = {"disconnect": (0.0, 8.9), "stall_short": (0.5, 0.03), "crc": (0.25, 0.04), "stall_long": (3.0, 8.9),
           "garbage_burst": (0.25, 0.9), "drop": (0.25, 0.02), "garbage_stream": (15.0, 16.0)}
"""Fault kind -> (its length, the outage after its end) as the slow smoke measured them (ded1ce8; the
garbage stream's 16 s in the first run one fault at a time, 10.4 s before)."""
SILENT = ("disconnect", "stall_short", "stall_long", "garbage_stream")
"""Kinds during which the emulator sends nothing (a stall, a boot, another device's bytes)."""


def _model_frame(t: float, faults, sent, handled, schedule) -> None:
    """The frame due at ``t``: sent unless a fault silences the controller, handled 5 ms later
    unless a fault's outage covers it."""
    down = [f for f in faults if f.start <= t < f.end + OUTAGES[f.kind][1]]
    if any(f.kind in SILENT for f in down):
        return
    sent.append((len(sent) * 31, t, len(sent)))
    if not down:
        handled[len(sent) - 1] = t + 0.005
        schedule.handled(t, t + 0.005)


def _faults_due(schedule) -> list[str]:
    """The faults ``schedule`` starts now (model drops and reloads due are passed over)."""
    out = []
    while (due := schedule.due()) is not None:
        if due[0] == "fault":
            out.append(due[1])
            break
    return out


def test_the_rollback_leaves_model_a_the_newest_valid_file_as_the_guide_says(tmp_path):
    """The newest modification time serves (7c4491f); docs/GUIDE.md rolls back by removing the newer
    file. A copy of a with an old mtime, as the soak once dropped, left b newest and serving."""
    from benchmarks.soak import Soak

    soak = object.__new__(Soak)  # only what swap() reads
    soak.models, soak.swaps, soak.t0 = tmp_path / "models", [], 0.0
    soak.model_a, soak.model_b = tmp_path / "a.onnx", tmp_path / "b.onnx"
    soak.model_a.write_bytes(b"a" * 64)
    soak.model_b.write_bytes(b"b" * 64)
    soak.ids, soak.expected_model = {"a": "id-a", "b": "id-b"}, "id-a"
    soak.good = [(harness_install(soak.model_a, soak.models, "a.onnx"), "a")]
    start = time.time() - 600
    for k, what in enumerate(S.SWAPS[: S.SWAPS.index("rollback") + 1]):
        soak.swap(what)
        for path in soak.models.glob(f"{k:03d}-*"):
            if path.stat().st_mtime > start:  # dropped now, not a copy that keeps an old mtime
                os.utime(path, (start + 8 * k, start + 8 * k))  # 8 s apart, as in the smoke
    assert soak.swaps[-1]["expect"] == "id-a"
    valid = [p for p in soak.models.iterdir() if p.read_bytes() in (b"a" * 64, b"b" * 64)
             and not p.stat().st_mode & 0o022]
    assert max(valid, key=lambda p: p.stat().st_mtime_ns).read_bytes() == b"a" * 64


def test_the_frame_log_is_read_as_it_grows(tmp_path):
    """The schedule follows the daemon's frame log while it is written: whole records, each once."""
    from benchmarks.soak_daemon import RECORD, FrameLogTail, read_frame_log

    log = tmp_path / "frames.bin"
    tail = FrameLogTail(log)
    assert tail.read() == ([], [])  # not yet written
    log.write_bytes(RECORD.pack(31, 1.5) + RECORD.pack(62, 1.53) + RECORD.pack(93, 1.56)[:7])
    assert tail.read() == ([31, 62], [1.5, 1.53])
    with open(log, "ab") as fh:
        fh.write(RECORD.pack(93, 1.56)[7:])
    assert tail.read() == ([93], [1.56]) and tail.read() == ([], [])
    assert read_frame_log(log) == ([31, 62, 93], [1.5, 1.53, 1.56])


def harness_install(source, folder, name):
    from trainer.bench.harness import install_model

    path = install_model(source, folder, name)
    old = time.time() - 86400
    os.utime(path, (old, old))  # a's mtime is older than b's will ever be (Soak.prepare_models)
    return path


@pytest.mark.slow
def test_soak_smoke(tmp_path):
    """Two minutes of soak with every fault kind but hangs, one at a time: nothing lost outside a
    fault, every fault recovered, events expected and none lost, the watchdog never silent while
    healthy, every model drop (the rollback too) served right, the files written."""
    from benchmarks.__main__ import main as bench

    assert bench(["soak", "--hours", str(SMOKE_HOURS), "--out", str(tmp_path), "--quiet"]) == 0
    r = json.loads((tmp_path / "soak.json").read_text())
    for key in ("hours", "frames_expected", "frames_lost_outside_injected_faults", "faults_injected",
                "faults_recovered", "max_recovery_s", "events_lost", "rss_growth_mb", "watchdog_would_fire",
                "hostile_inputs"):
        assert key in r, key
    assert r["frames_expected"] > 1000
    assert r["frames_lost_outside_injected_faults"] == 0, r["lost_outside_examples"]
    assert r["faults_injected"] >= 7 and r["faults_recovered"] == r["faults_injected"], r["fault_log"]
    assert r["events_expected"] > 0 and r["events_lost"] == 0, r["events_lost_at_s"]
    assert r["watchdog_would_fire_while_healthy"] == 0
    assert r["model_swaps"]["right"] == r["model_swaps"]["dropped"], r["model_swaps"]["wrong"]
    assert r["daemon_log"]["tracebacks"] == 0
    assert (tmp_path / "soak.md").read_text().startswith("# Soak")
