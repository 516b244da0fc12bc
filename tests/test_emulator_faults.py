"""The emulator's faults are real (issue 18 item 6): single frames come at the sensor's rate, a
disconnect over the pseudo-terminal loses data and ends push mode as an unplug does, and a
replayed file's sensor serial number is what the client reads. Data: the simulated hand (synthetic)."""

from __future__ import annotations

import dataclasses
import itertools
import time

import pytest

from firmware_io.client import DSAClient
from firmware_io.emulator.device import DeviceEmulator, FaultPlan
from firmware_io.emulator.frame_source import load_source
from firmware_io.emulator.server import EmulatorServerError, PtyEmulatorServer, TcpEmulatorServer
from firmware_io.wire.errors import DSAError

QUICK = {"gap_timeout": 0.3, "stop_timeout": 0.3, "flush_max": 0.3, "flush_quiet": 0.05}


def _recording(**meta):
    rec = load_source("sim", seed=0, events=2)
    return dataclasses.replace(rec, meta={**rec.meta, **meta}) if meta else rec


def test_single_frames_come_at_the_sensors_rate():
    rec = _recording()
    server = TcpEmulatorServer(DeviceEmulator(rec, speed=1.0)).start()
    try:
        with DSAClient(server.url, **QUICK) as client:
            client.poll_frame()
            t0 = time.monotonic()
            stamps = [client.poll_frame(timeout=1.0).timestamp_ms for _ in range(16)]
            took = time.monotonic() - t0
    finally:
        server.stop()
    period = rec.sample_interval()
    assert took >= 16 * period * 0.8, f"16 single frames in {took * 1000:.0f} ms (sensor: {period * 1000:.0f} ms each)"
    assert all(b > a for a, b in itertools.pairwise(stamps))


def test_a_power_cycle_over_the_pty_ends_push_mode_and_the_controller_boots_before_answering():
    """``disconnect`` on a pty is a power cycle: push mode ends, the controller is deaf while it
    boots (here 3 s, ESC[5n at 2.5 s): a short open fails, one with time to spare waits it out."""
    rec = _recording()
    emulator = DeviceEmulator(rec, speed=None, faults=FaultPlan(disconnect_after=40), boot_s=3.0, boot_query_s=2.5)
    try:
        server = PtyEmulatorServer(emulator).start()
    except EmulatorServerError as exc:
        pytest.skip(f"no pseudo-terminal here: {exc}")
    try:
        client = DSAClient(server.url, auto_reconnect=False, restart_stalled_s=None, **QUICK)
        client.open()
        client.start()
        frames = 0
        while client.read_frame(timeout=0.5) is not None:
            frames += 1
            assert frames < 500, "frames keep coming after the unplug"
        assert frames <= 40 and not emulator.pushing and emulator.booting
        client.open_timeout = 0.5
        with pytest.raises(DSAError):
            client.open()  # nobody answers while it boots
        assert emulator.booting
        client.open_timeout = 10.0
        client.open()  # an open within its deadline waits the boot out, as SDHLibrary's does
        assert not emulator.booting
        client.start()
        assert client.read_frame(timeout=1.0) is not None
        assert client.stats["boot_queries"] >= 1
        client.close()
    finally:
        server.stop()
    assert emulator.stats.disconnects >= 1 and emulator.stats.power_cycles >= 1


def test_the_reader_restarts_acquisition_after_a_power_cycle_over_the_pty():
    """The reader alone (as handover dump uses it) keeps reading across two power cycles: after
    the boot query it sends the push start again, and frames resume."""
    rec = _recording()
    emulator = DeviceEmulator(rec, speed=4.0, faults=FaultPlan(disconnect_after=60), boot_s=1.5, boot_query_s=1.2)
    try:
        server = PtyEmulatorServer(emulator).start()
    except EmulatorServerError as exc:
        pytest.skip(f"no pseudo-terminal here: {exc}")
    try:
        client = DSAClient(server.url, auto_reconnect=False, **QUICK)
        client.open()
        client.start()
        frames, stamps = 0, []
        deadline = time.monotonic() + 30
        while emulator.stats.power_cycles < 2 or frames < 150:
            assert time.monotonic() < deadline, f"{frames} frames, {emulator.stats.power_cycles} power cycles"
            frame = client.read_frame(timeout=0.5)
            if frame is not None:
                frames += 1
                stamps.append(frame.timestamp_ms)
        assert client.stats["restarts"] >= 2
        client.close()
    finally:
        server.stop()


def test_the_replayed_files_sensor_serial_number_is_served():
    rec = _recording(dsa_serial_nr="1D9B0057", dsa_hw_revision="2")  # hex without 0x, as DSA-Konqueror writes it
    server = TcpEmulatorServer(DeviceEmulator(rec, speed=None, serial_no=99)).start()
    try:
        with DSAClient(server.url, **QUICK) as client:
            assert client.sensor.serial_no == 0x1D9B0057 and client.sensor.hw_revision == 2
            assert client.controller.serial_no == 99
    finally:
        server.stop()


def test_a_recorded_sessions_sensor_serial_number_is_served():
    rec = _recording(sessions=[{"controller": {"serial_no": 5, "sensor_serial_no": 31337}}])
    assert DeviceEmulator(rec).sensor.serial_no == 31337


def test_a_real_dsa_files_sensor_serial_is_what_the_client_reads():
    """A real DSA-Konqueror file replayed: its ``<serial_nr>`` is hex without 0x (1D9B0057)."""
    from tests.conftest import real_data_dir

    path = real_data_dir() / "kiechle/pressure_profiles/frequency_analysis/sliptest_highspeed_xmasball.dsa"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    rec = load_source(path)
    assert rec.meta["dsa_serial_nr"] == "1D9B0057"
    server = TcpEmulatorServer(DeviceEmulator(rec, speed=None)).start()
    try:
        with DSAClient(server.url, **QUICK) as client:
            assert client.sensor.serial_no == 0x1D9B0057
    finally:
        server.stop()
