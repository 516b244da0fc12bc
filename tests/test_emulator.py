"""The emulated DSACON32m at the byte level: every command, error codes, frames, timing, faults."""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import re

import numpy as np
import pytest

from firmware_io.emulator.device import DeviceEmulator, FaultPlan, FaultSpecError
from firmware_io.emulator.frame_source import placeholder_session
from firmware_io.wire import replies, requests
from firmware_io.wire.device_time import TimestampUnwrapper
from firmware_io.wire.errors import DeviceError, DSAErrorCode
from firmware_io.wire.frames import decode_frame_payload
from firmware_io.wire.packets import Packet, encode_ack, encode_packet, error_code_of
from firmware_io.wire.parser import StreamParser
from tests.clocks import ManualClock


@pytest.fixture(scope="module")
def rec():
    return placeholder_session(seed=1, events=1)


def make(rec, **kw):
    clock = ManualClock(100.0)
    emu = DeviceEmulator(rec, clock=clock, **kw)
    emu.connect()
    return emu, clock


def ask(emu, packet: bytes) -> list[Packet]:
    emu.feed(packet)
    return StreamParser(emu.layout.n_taxels).feed(emu.read(1 << 20))


def test_queries_answer_with_reference_sizes(rec):
    emu, _ = make(rec)
    (ctrl,) = ask(emu, requests.query_controller_info_request())
    assert ctrl.packet_id == 0x01 and len(ctrl.payload) == 18
    assert replies.ControllerInfo.decode(ctrl.payload).firmware == "2.9.0.0"
    (sens,) = ask(emu, requests.query_sensor_info_request())
    assert replies.SensorInfo.decode(sens.payload).nb_matrices == 6
    layout = rec.layout
    for m in range(6):
        (mi,) = ask(emu, requests.query_matrix_info_request(m))
        assert len(mi.payload) == 52
        info = replies.MatrixInfoReply.decode(mi.payload).to_matrix_info(m)
        assert (info.cells_x, info.cells_y) == (layout.matrices[m].cells_x, layout.matrices[m].cells_y)
    (mask,) = ask(emu, requests.read_matrix_mask_request(1))
    assert np.array_equal(replies.MatrixMaskReply.decode(mask.payload).to_mask(6, 13), layout.matrices[1].mask)


def test_errors_unknown_command_bad_index_short_payload(rec):
    emu, _ = make(rec)
    emu.feed(encode_packet(0x77, b"\x01"))
    assert emu.read() == encode_ack(0x77, DSAErrorCode.CMD_UNKNOWN)
    (r,) = ask(emu, requests.query_matrix_info_request(6))
    assert error_code_of(r.payload) == DSAErrorCode.INDEX_OUT_OF_BOUNDS
    with pytest.raises(DeviceError):
        replies.MatrixInfoReply.decode(r.payload)
    (r,) = ask(emu, encode_packet(0x0B, b""))
    assert error_code_of(r.payload) == DSAErrorCode.CMD_NOT_ENOUGH_PARAMS
    (r,) = ask(emu, encode_packet(0x03, b"\x80\x01\x00\x00"))
    assert error_code_of(r.payload) == DSAErrorCode.CMD_FORMAT_ERROR
    assert emu.stats.unknown_commands == 1


def test_sensitivity_and_threshold_round_trip_and_persistent_silence(rec):
    emu, _ = make(rec)
    (r,) = ask(emu, requests.SetThresholdRequest(2, 150).to_packet())
    assert error_code_of(r.payload) == 0
    (r,) = ask(emu, requests.get_threshold_request(2))
    assert replies.ThresholdReply.decode(r.payload).threshold == 150
    assert ask(emu, requests.SetThresholdRequest(3, 99, persistent=True).to_packet()) == []
    (r,) = ask(emu, requests.get_threshold_request(3))
    assert replies.ThresholdReply.decode(r.payload).threshold == 99
    (r,) = ask(emu, requests.SetSensitivityRequest(1, 0.25).to_packet())
    assert error_code_of(r.payload) == 0
    (r,) = ask(emu, requests.get_sensitivity_request(1))
    reply = replies.SensitivityReply.decode(r.payload)
    assert reply.cur_sens == pytest.approx(0.25) and reply.fact_sens == pytest.approx(0.5)
    assert ask(emu, requests.SetSensitivityRequest(1, 0.75, persistent=True).to_packet()) == []
    bad = encode_packet(0x13, bytes([0, 0]) + (5000).to_bytes(2, "little"))
    (r,) = ask(emu, bad)
    assert error_code_of(r.payload) == DSAErrorCode.RANGE_ERROR


@pytest.mark.parametrize("rle", [True, False])
def test_push_frames_equal_recording_and_follow_its_timing(rec, rle):
    emu, clock = make(rec, speed=1.0)
    packets = ask(emu, requests.push_request(rle=rle))
    assert packets[0].packet_id == 0x03 and error_code_of(packets[0].payload) == 0
    parser = StreamParser(rec.layout.n_taxels)
    got = [p for p in packets[1:]]
    while len(got) < 20:
        clock.t += 0.01
        got += parser.feed(emu.read(1 << 16))
    assert all(p.packet_id == 0 for p in got)
    for i, p in enumerate(got[:20]):
        ts, values = decode_frame_payload(p.payload, rec.layout.n_taxels)
        assert bool(p.payload[4] & 1) == rle
        assert np.array_equal(values, rec.frames[i])
        assert ts == round((rec.timestamps[i] - rec.timestamps[0]) * 1000)
    # nothing is sent before it is due
    assert emu.seconds_until_output() > 0
    assert emu.read() == b""


def test_single_frame_and_old_firmware_push_bug(rec):
    emu, clock = make(rec, speed=1.0)
    packets = ask(emu, requests.single_frame_request())
    assert [p.packet_id for p in packets] == [0x03, 0x00]
    clock.t += 1.0
    assert emu.read() == b"" and not emu.pushing
    old, clock = make(rec, speed=1.0, old_firmware=True)
    (ctrl,) = ask(old, requests.query_controller_info_request())
    assert replies.ControllerInfo.decode(ctrl.payload).single_frame_broken
    ask(old, requests.single_frame_request())
    clock.t += 1.0
    assert old.pushing and len(StreamParser(486).feed(old.read(1 << 20))) > 10
    ask(old, requests.stop_request())
    clock.t += 1.0
    assert old.read() == b""


def test_max_speed_no_loop_finishes(rec):
    emu, _ = make(rec, speed=None, loop=False)
    emu.feed(requests.push_request())
    parser = StreamParser(rec.layout.n_taxels)
    frames = []
    for _ in range(1000):
        frames += [p for p in parser.feed(emu.read(4096)) if p.packet_id == 0]
        if emu.finished:
            break
    assert len(frames) == rec.n_frames and emu.finished


def test_loop_continues_device_time(rec):
    emu, _ = make(rec, speed=None, loop=True, start_ms=(1 << 32) - 500)
    emu.feed(requests.push_request())
    parser = StreamParser(rec.layout.n_taxels)
    frames = []
    while len(frames) < rec.n_frames + 3:
        frames += [p for p in parser.feed(emu.read(1 << 16)) if p.packet_id == 0]
    unwrap = TimestampUnwrapper()
    stamps = [unwrap(decode_frame_payload(p.payload, 486)[0]) for p in frames]
    assert np.all(np.diff(stamps) > 0)  # across the loop and across the u32 wrap
    assert np.array_equal(decode_frame_payload(frames[rec.n_frames].payload, 486)[1], rec.frames[0])


def test_faults_are_counted_by_emulator_and_parser(rec):
    plan = FaultPlan.parse("crc=0.05,garbage=0.05,drop=0.05,boot")
    emu, _ = make(rec, speed=None, faults=plan, seed=3)
    parser = StreamParser(rec.layout.n_taxels)
    parser.feed(emu.read(1 << 16))  # boot query before anything
    emu.feed(requests.push_request())
    good = 0
    while emu.stats.frames_sent < 300:
        for p in parser.feed(emu.read(1 << 16)):
            if p.packet_id == 0:
                decode_frame_payload(p.payload, 486)
                good += 1
    s = emu.stats
    assert s.crc_corrupted > 0 and s.garbage_inserted > 0 and s.packets_truncated > 0
    assert parser.stats.boot_queries == 3
    assert parser.stats.crc_errors >= s.crc_corrupted
    # every frame not hit by a fault survives the faults around it
    assert good >= 300 - s.crc_corrupted - s.packets_truncated - s.garbage_inserted


def test_stall_and_disconnect(rec):
    emu, clock = make(rec, speed=None, faults=FaultPlan(stall=1.0, stall_seconds=0.5, disconnect_after=3))
    emu.feed(requests.push_request())
    assert emu.read(1 << 16)  # ack + first frame, then the stall starts
    assert emu.read(1 << 16) == b"" and emu.seconds_until_output() == pytest.approx(0.5)
    clock.t += 0.6
    assert emu.read(1 << 16)
    clock.t += 0.6
    emu.read(1 << 16)
    assert emu.disconnected and emu.read() == b"" and emu.stats.disconnects == 1
    emu.connect()
    assert not emu.disconnected


@pytest.mark.parametrize(
    "text, said", [("crc=2", "a probability from 0 to 1, e.g. crc=0.02"), ("bogus=1", "known: crc"),
                   ("stall=0.1:0", "0 < SECONDS <= 60"), ("disconnect=0", "at least 1"),
                   ("garbage=x", "a probability from 0 to 1"), ("boot=3", "nothing (on), or on/off")]
)
def test_fault_spec_errors_say_what_to_give(text, said):
    with pytest.raises(FaultSpecError, match=re.escape(said)):
        FaultPlan.parse(text)


def test_fault_spec_parses():
    plan = FaultPlan.parse("crc=0.01, garbage=0.02,drop=0.03,stall=0.004:0.25,disconnect=300,boot")
    assert (plan.crc, plan.garbage, plan.drop, plan.stall, plan.stall_seconds) == (0.01, 0.02, 0.03, 0.004, 0.25)
    assert plan.disconnect_after == 300 and plan.boot_query and plan.any
    assert not FaultPlan.parse("").any
    assert FaultPlan.parse("boot=on").boot_query and not FaultPlan.parse("boot=off").any


# -- fidelity to the real controller: clock, pacing, power cycle ------------------------------------


def _frames(emu, parser=None) -> list[tuple[int, np.ndarray]]:
    parser = parser or StreamParser(486)
    return [decode_frame_payload(p.payload, 486) for p in parser.feed(emu.read(1 << 20)) if p.packet_id == 0]


def test_the_device_clock_runs_while_nothing_is_sent(rec):
    """Acquisition paused 3 s: the next frame's timestamp is about 3 s later, and it is the frame the
    sensor sees then, not the one after the last sent; single frames asked 0.55 s apart are that far apart."""
    emu, clock = make(rec, speed=1.0, start_ms=5000)
    _ack, first = ask(emu, requests.push_request())
    assert decode_frame_payload(first.payload, 486)[0] == 5000  # the clock's start value
    clock.t += 0.2
    before = _frames(emu)
    ask(emu, requests.stop_request())
    clock.t += 3.0
    ask(emu, requests.push_request())
    clock.t += 0.05
    after = _frames(emu)
    gap = after[0][0] - before[-1][0]
    assert 2900 <= gap <= 3100, gap
    stamps = []
    ask(emu, requests.stop_request())
    for _ in range(3):
        clock.t += 0.5
        emu.feed(requests.single_frame_request())
        clock.t += 0.05
        stamps += [ts for ts, _ in _frames(emu)]
    assert [b - a for a, b in itertools.pairwise(stamps)] == pytest.approx([550, 550], abs=35)  # asked every 0.55 s
    i = int(np.searchsorted(rec.timestamps - rec.timestamps[0], (stamps[-1] - 5000) / 1000 - 1e-6))
    assert np.array_equal(_frame_at(emu, stamps[-1]), rec.frames[i])
    assert emu.stats.frames_skipped > 50


def _frame_at(emu, stamp: int) -> np.ndarray:
    emu.feed(requests.stop_request())
    emu.read(1 << 20)
    rel = np.round((emu.recording.timestamps - emu.recording.timestamps[0]) * 1000).astype(int)
    return emu.recording.frames[int(np.searchsorted(rel, stamp - emu.start_ms))]


def test_raw_frames_are_paced_by_the_line_rate(rec):
    """115200 baud carries 11520 bytes/s: raw frames (985 bytes) come at about 11.7 per second, each
    the newest the sensor saw; RLE frames of a quiet pad still come at the sensor's rate."""
    emu, clock = make(rec, speed=1.0)
    emu.set_line_rate(115200 / 10)
    parser = StreamParser(486)
    ask(emu, requests.push_request(rle=False))
    got, sent = [], 0
    for _ in range(2000):  # 2 s in 1 ms steps
        clock.t += 0.001
        data = emu.read(1 << 16)
        sent += len(data)
        got += [p for p in parser.feed(data) if p.packet_id == 0]
    assert sent <= 2.0 * 11520 + 200
    assert 20 <= len(got) <= 24, len(got)
    stamps = [decode_frame_payload(p.payload, 486)[0] for p in got]
    assert min(np.diff(stamps)) >= 62  # frames in between went by
    quiet = dataclasses.replace(rec, frames=np.zeros_like(rec.frames))
    emu2, clock2 = make(quiet, speed=1.0)
    emu2.set_line_rate(115200 / 10)
    ask(emu2, requests.push_request(rle=True))
    n, parser = 0, StreamParser(486)
    for _ in range(1000):
        clock2.t += 0.001
        n += sum(p.packet_id == 0 for p in parser.feed(emu2.read(1 << 16)))
    assert n >= 28  # 1 s at 32 Hz: small frames fit the line


def test_a_power_cycle_takes_the_boot_time_and_forgets_what_was_not_stored(rec):
    emu, clock = make(rec, speed=1.0, start_ms=1000)
    ask(emu, requests.SetThresholdRequest(2, 150).to_packet())
    ask(emu, requests.SetThresholdRequest(3, 99, persistent=True).to_packet())
    ask(emu, requests.SetSensitivityRequest(1, 0.25).to_packet())
    ask(emu, requests.SetSensitivityRequest(4, 0.75, persistent=True).to_packet())
    ask(emu, requests.push_request())
    clock.t += 2.0
    emu.read(1 << 20)
    emu.power_cycle()
    parser = StreamParser(486)
    answered_at, query_at = None, None
    for step in range(100):  # 10 s in 0.1 s steps, asking for the controller info each step
        clock.t += 0.1
        emu.feed(requests.query_controller_info_request())
        packets = parser.feed(emu.read(1 << 16))
        if parser.stats.boot_queries and query_at is None:
            query_at = (step + 1) * 0.1
        if packets and answered_at is None:
            answered_at = (step + 1) * 0.1
    assert query_at == pytest.approx(7.0, abs=0.15) and answered_at == pytest.approx(8.0, abs=0.15)
    assert not emu.pushing and emu.stats.power_cycles == 1

    def threshold(m):
        return replies.ThresholdReply.decode(ask(emu, requests.get_threshold_request(m))[0].payload).threshold

    def sensitivity(m):
        return replies.SensitivityReply.decode(ask(emu, requests.get_sensitivity_request(m))[0].payload).cur_sens

    assert (threshold(2), threshold(3)) == (0, 99)
    assert sensitivity(1) == pytest.approx(0.5) and sensitivity(4) == pytest.approx(0.75)
    ask(emu, requests.push_request())
    clock.t += 0.05
    (ts, _), *_ = _frames(emu)
    assert 1000 + 10000 - 100 <= ts <= 1000 + 10000 + 100  # the clock restarted at power-on, 10 s ago


def test_a_session_played_to_a_late_host_starts_when_it_first_asks(rec):
    """``session_starts="first_acquisition"``: the recording starts at the host's first request (its
    first frame is the recording's first), the clock has run since power-on all the same."""
    emu, clock = make(rec, speed=1.0, start_ms=100, session_starts="first_acquisition")
    clock.t += 12.5
    assert emu.session_clock_ms is None
    _, first = ask(emu, requests.push_request())
    ts, values = decode_frame_payload(first.payload, 486)
    assert np.array_equal(values, rec.frames[0]) and ts == 100 + 12500 == emu.session_clock_ms


def test_the_emulators_default_session_is_not_one_the_demo_trains_on():
    """The README's daemon recipe serves the demo's model against ``handover emulate``: by default it
    must play people the model never saw, as ``handover demo`` does (the simulator draws its people and
    hand from the seed, so a session under a training seed replays the trained subjects)."""
    import importlib

    from firmware_io.sim.scenario import make_subject
    from firmware_io.sim.session import DEMO_SESSION_SEED, DEMO_TRAIN_SEED
    from firmware_io.sim.streams import stream
    from runtime import cli
    from trainer.commands.demo_cli import scripted_session

    def defaults(name, *argv):
        return cli.build_parser(name, importlib.import_module(cli.COMMANDS[name][0])).parse_args(list(argv))

    emulated = defaults("emulate", "--pty").seed
    trained = defaults("demo").seed  # the protocol, the idle stream and the stream model's session (fit_stream_model)
    assert trained == DEMO_TRAIN_SEED and emulated == DEMO_SESSION_SEED
    from benchmarks import dormant_cli

    dormant = argparse.ArgumentParser()
    dormant_cli.add_arguments(dormant)
    assert emulated not in {trained, defaults("train").seed, dormant.parse_args([]).seed}
    assert make_subject("s1", stream(emulated, "subject", "s1")) != make_subject("s1", stream(trained, "subject", "s1"))
    session_seed, _script, _ = scripted_session(trained, events=4)
    assert session_seed == emulated  # the recipe plays the demo's own session
    helped = " ".join(cli.build_parser("emulate", importlib.import_module(cli.COMMANDS["emulate"][0])).format_help().split())
    assert f"(default {DEMO_SESSION_SEED}: the demo's scripted session, by simulated subjects no demo model trains on" in helped
