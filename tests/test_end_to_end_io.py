"""The real client against the emulator over real links: a loopback TCP socket, a pseudo-terminal
opened through pyserial, the in-process sim:// and replay:// transports, and the two CLIs."""

from __future__ import annotations

import argparse
import itertools
import json
import subprocess
import sys

import numpy as np
import pytest

from firmware_io.client import DSAClient
from firmware_io.emulator.device import DeviceEmulator, FaultPlan
from firmware_io.emulator.frame_source import placeholder_session
from firmware_io.emulator.server import EmulatorServerError, PtyEmulatorServer, TcpEmulatorServer
from firmware_io.layout import SensorLayout
from firmware_io.transports import DeviceUnavailable, EndOfStream
from tests.conftest import ROOT, dsa_files


@pytest.fixture(scope="module")
def rec():
    return placeholder_session(seed=4, events=1)


def client_for(url: str, **kw) -> DSAClient:
    opts = dict(gap_timeout=0.5, stop_timeout=1.0, flush_quiet=0.05, flush_max=0.3, backoff_initial=0.05)
    opts.update(kw)
    return DSAClient(url, **opts)


def sdh2_cells(layout: SensorLayout) -> list[tuple[int, int]]:
    return [(m.cells_x, m.cells_y) for m in layout.matrices]


def read_n(client: DSAClient, n: int) -> list:
    frames = []
    for _ in range(n):
        f = client.read_frame(timeout=3.0)
        assert f is not None, f"no frame after {len(frames)}: {client.stats}"
        frames.append(f)
    return frames


@pytest.mark.parametrize("rle", [True, False])
def test_tcp_server_frames_bit_for_bit(rec, rle):
    with TcpEmulatorServer(DeviceEmulator(rec, speed=None)) as server:
        client = client_for(server.url, rle=rle)
        layout = client.open()
        assert sdh2_cells(layout) == sdh2_cells(SensorLayout.sdh2())
        client.start()
        frames = read_n(client, rec.n_frames)
        client.close()
    stored = np.stack([f.values for f in frames])
    assert np.array_equal(stored, rec.frames)
    ms = np.round((rec.timestamps - rec.timestamps[0]) * 1000).astype(int)
    assert [f.timestamp_ms for f in frames] == ms.tolist()
    assert [f.number for f in frames] == list(range(rec.n_frames))
    assert client.stats["crc_errors"] == 0 and client.stats["bytes_dropped"] == 0


def test_pty_server_through_pyserial(rec):
    with PtyEmulatorServer(DeviceEmulator(rec, speed=4.0)) as server:
        assert server.path.startswith("/dev/")
        for url in (server.url, server.path):  # serial:///dev/pts/N and the plain path
            client = client_for(url)
            layout = client.open()
            assert sdh2_cells(layout) == sdh2_cells(SensorLayout.sdh2())
            client.start()
            frames = read_n(client, 10)
            client.close()
            # each frame is the one the sensor saw at its device time (the line, 115200 baud, carries
            # fewer of these noisy frames than the sensor makes at speed 4: those in between go by)
            ms = np.round((rec.timestamps - rec.timestamps[0]) * 1000)
            period = ms[-1] + round(rec.sample_interval() * 1000)
            for f in frames:
                assert np.array_equal(f.values, rec.frames[int(np.searchsorted(ms, f.timestamp_ms % period))])
            assert all(b.timestamp_ms > a.timestamp_ms for a, b in itertools.pairwise(frames))


def test_faults_are_counted_and_the_client_recovers(rec):
    plan = FaultPlan.parse("crc=0.03,garbage=0.03,drop=0.03,stall=0.01:0.2,boot")
    emulator = DeviceEmulator(rec, speed=None, faults=plan, seed=7)
    with TcpEmulatorServer(emulator) as server:
        client = client_for(server.url)
        client.open()
        client.start()
        frames = read_n(client, 250)
        client.close()
    s, c = emulator.stats, client.stats
    assert s.crc_corrupted and s.garbage_inserted and s.packets_truncated and s.stalls
    assert c["crc_errors"] >= s.crc_corrupted > 0
    assert c["bytes_dropped"] >= s.garbage_bytes
    assert c["boot_queries"] == 3
    ms = np.round((rec.timestamps - rec.timestamps[0]) * 1000).astype(int)
    period = round(emulator._loop_period * 1000)
    for f in frames:  # every frame that arrived is an exact frame of the source
        _loops, rel = divmod(f.timestamp_ms, period)
        i = int(np.searchsorted(ms, rel))
        assert np.array_equal(f.values, rec.frames[i])
    assert frames[-1].number >= len(frames) - 1


def test_disconnect_then_reconnect(rec):
    emulator = DeviceEmulator(rec, speed=None, faults=FaultPlan(disconnect_after=40), boot_s=1.0, boot_query_s=0.5)
    with TcpEmulatorServer(emulator) as server:
        client = client_for(server.url, auto_reconnect=False)
        client.open()
        client.start()
        with pytest.raises(DeviceUnavailable):
            for _ in range(200):
                client.read_frame(timeout=2.0)
        layout = client.reconnect()
        assert sdh2_cells(layout) == sdh2_cells(SensorLayout.sdh2())
        assert client.streaming
        assert len(read_n(client, 10)) == 10
        assert client.stats["reconnects"] == 1
        client.close()
    assert emulator.stats.disconnects >= 1 and emulator.stats.connections >= 2


def test_auto_reconnect_keeps_frames_coming(rec):
    emulator = DeviceEmulator(rec, speed=None, faults=FaultPlan(disconnect_after=30), boot_s=1.0, boot_query_s=0.5)
    with TcpEmulatorServer(emulator) as server:
        client = client_for(server.url)
        client.open()
        client.start()
        read_n(client, 80)
        assert client.stats["reconnects"] >= 1
        client.close()


def test_sim_and_replay_urls(rec, tmp_path):
    client = client_for("sim://?events=1&realtime=0")
    layout = client.open()
    assert layout.n_taxels == 486
    client.start()
    assert len(read_n(client, 5)) == 5
    client.close()

    path = rec.save(tmp_path / "session.hrec")
    client = client_for(f"replay://{path}?speed=max", auto_reconnect=False)
    client.open()
    client.start()
    frames = read_n(client, rec.n_frames)
    assert np.array_equal(np.stack([f.values for f in frames]), rec.frames)
    with pytest.raises(EndOfStream):
        client.read_frame(timeout=1.0)
    client.close()


def test_replay_realtime_paces_frames(rec, tmp_path):
    path = rec.save(tmp_path / "paced.hrec")
    client = client_for(f"replay://{path}?speed=2")
    client.open()
    client.start()
    frames = read_n(client, 9)
    client.close()
    elapsed = frames[-1].received - frames[0].received
    recorded = (rec.timestamps[8] - rec.timestamps[0]) / 2
    assert elapsed > 0.5 * recorded  # paced by the recording, not as fast as possible


@pytest.mark.realdata
def test_replay_of_a_real_dsa_recording(sdh2_data):
    from firmware_io.recordings.importers import import_any

    path = min(dsa_files(), key=lambda p: p.stat().st_size)
    real = import_any(path)
    client = client_for("replay://" + str(path) + "?speed=max", auto_reconnect=False)
    layout = client.open()
    assert layout.n_taxels == real.layout.n_taxels
    client.start()
    n = min(real.n_frames, 40)
    frames = read_n(client, n)
    client.close()
    assert np.array_equal(np.stack([f.values for f in frames]), real.frames[:n])


def test_tcp_server_refuses_non_loopback(rec):
    with pytest.raises(EmulatorServerError, match="loopback only"):
        TcpEmulatorServer(DeviceEmulator(rec), host="0.0.0.0")


def test_emulate_on_a_taken_port_says_to_pick_another_or_0(capsys):
    import socket

    from runtime.cli import main as handover

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        assert handover(["emulate", "--listen", f"tcp://127.0.0.1:{port}", "--duration", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"handover emulate: cannot listen on 127.0.0.1:{port}: ") and "\n" not in err
    assert "give another port, or port 0 to pick a free one" in err


def _args(module, argv):
    parser = argparse.ArgumentParser()
    module.add_arguments(parser)
    return parser.parse_args(argv)


def test_dump_cli_prints_layout_frames_and_summary(capsys):
    from firmware_io.commands import dump_cli

    assert dump_cli.main(_args(dump_cli, ["sim://?events=1&realtime=0", "--frames", "4"])) == 0
    out = capsys.readouterr().out
    assert "6 pads, 486 taxels" in out and "4 frames" in out and "crc_errors 0" in out
    assert dump_cli.main(_args(dump_cli, ["sim://?events=1&realtime=0", "--frames", "3", "--json"])) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert [x["type"] for x in lines] == ["layout", "frame", "frame", "frame", "summary"]
    assert len(lines[1]["pad_sums"]) == 6 and lines[-1]["frames"] == 3


def test_dump_cli_errors_are_one_line(capsys):
    from runtime import cli

    assert cli.main(["dump", "bogus://x"]) == 2  # a URL that can never open: the user's to fix
    err = capsys.readouterr().err.strip()
    assert err.startswith("handover dump: bogus://x: unknown scheme 'bogus://'") and "\n" not in err


def test_emulate_cli_serves_tcp_to_dump(tmp_path):
    proc = subprocess.Popen(
        [sys.executable, "-m", "runtime.cli", "emulate", "--listen", "tcp://127.0.0.1:0", "--events", "1",
         "--speed", "max", "--duration", "20"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        url = None
        for _ in range(5):
            line = proc.stdout.readline()
            if line.startswith("listening: "):
                url = line.split()[1]
                break
        assert url and url.startswith("tcp://127.0.0.1:")
        # another process on a machine whose cores are busy can be silent for more than half a second
        client = client_for(url, gap_timeout=5.0, stop_timeout=10.0)
        assert client.open().n_taxels == 486
        client.start()
        assert len(read_n(client, 20)) == 20
        client.close()
    finally:
        proc.terminate()
        proc.communicate(timeout=10)


def test_emulate_cli_stops_cleanly_on_sigterm_with_a_summary():
    proc = subprocess.Popen(
        [sys.executable, "-m", "runtime.cli", "emulate", "--listen", "tcp://127.0.0.1:0", "--events", "1"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        for _ in range(5):
            if proc.stdout.readline().startswith("listening: "):
                break
        proc.terminate()
        out, err = proc.communicate(timeout=10)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert "served 0 connection(s)" in out


def test_tcp_server_on_ipv6_loopback(rec):
    try:
        server = TcpEmulatorServer(DeviceEmulator(rec, speed=None), host="[::1]")
    except EmulatorServerError as exc:
        pytest.skip(f"no IPv6 loopback here: {exc}")
    with server:
        assert server.url.startswith("tcp://[::1]:")
        client = client_for(server.url)
        assert client.open().n_taxels == rec.layout.n_taxels
        client.close()


def test_emulate_cli_bad_options_are_one_line(capsys):
    from runtime.cli import main

    for argv, words in [
        (["--listen", "tcp://10.1.2.3:5000"], "loopback only"),
        (["--listen", "udp://127.0.0.1:5"], "use tcp://"),
        (["--listen", "pty"], "or --pty for a pseudo-terminal"),  # the serial case is a flag, not a URL
        (["--pty", "--fault", "crc=7"], "--fault"),
        (["--pty", "--speed", "fast"], "--speed"),
        (["--pty", "--source", "/no/such.hrec"], "no such file"),
    ]:
        assert main(["emulate", *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("handover emulate: ") and words in err and "\n" not in err


def test_serial_asks_for_low_latency_mode_and_a_port_that_refuses_it_still_works(rec):
    """ftdi_sio holds a short packet 16 ms unless the port is in low-latency mode: the transport asks
    for it. A pty refuses (as a native UART or another OS would), and the port works all the same."""
    from firmware_io.transports import serial_port

    _pty_refuses_low_latency_and_serves(rec, opens=1)

    class AdapterPort:
        def __init__(self) -> None:
            self.asked: list[bool] = []

        def set_low_latency_mode(self, on: bool) -> None:
            self.asked.append(on)

    port = AdapterPort()
    assert serial_port._ask_low_latency(port) is True and port.asked == [True]
    assert serial_port._ask_low_latency(object()) is False  # pyserial off Linux has no such call


def test_a_low_latency_request_that_fails_otherwise_neither_blocks_nor_leaks_the_port(rec, monkeypatch):
    """pyserial's Linux set_low_latency_mode looks up termios.TIOCGSERIAL when called: a Python without
    it raised AttributeError out of the transport's constructor, so the daemon retried for ever a port
    that works. The request is a nicety: any failure leaves the port as it was, and the port opens
    (again: nothing left open and locked) and serves."""
    import termios

    monkeypatch.delattr(termios, "TIOCGSERIAL", raising=False)
    _pty_refuses_low_latency_and_serves(rec, opens=2)  # the second open finds the port free


def _pty_refuses_low_latency_and_serves(rec, opens: int) -> None:
    """Open the emulator's pty ``opens`` times (low-latency mode refused each time), then stream."""
    from firmware_io.transports import open_transport

    with PtyEmulatorServer(DeviceEmulator(rec, speed=4.0)) as server:
        for _ in range(opens):
            transport = open_transport(server.url)
            assert transport.low_latency is False
            transport.close()
        client = client_for(server.url)
        client.open()
        client.start()
        assert len(read_n(client, 3)) == 3
        client.close()
