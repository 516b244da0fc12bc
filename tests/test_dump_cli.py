"""``handover dump`` summaries: no phantom timeout at the end of --seconds, and an honest
receive rate for a source that sends as fast as possible (simulated hand, synthetic)."""

from __future__ import annotations

import json
import socket

import pytest

from runtime.cli import main


def _summary(capsys, *argv: str) -> dict:
    assert main(["dump", *argv, "--json"]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert lines[0]["type"] == "layout" and lines[-1]["type"] == "summary"
    return lines[-1]


def test_the_end_of_seconds_is_not_a_timeout(capsys):
    summary = _summary(capsys, "sim://", "--seconds", "0.5")
    assert summary["frames"] >= 10
    assert summary["stats"]["timeouts"] == 0
    assert 25 < summary["rate_hz"] < 40 and 25 < summary["device_rate_hz"] < 40  # paced at ~32 Hz


def test_as_fast_as_possible_says_so_instead_of_a_bare_null(capsys):
    summary = _summary(capsys, "sim://?realtime=0", "--frames", "30")
    assert summary["frames"] == 30 and summary["stats"]["timeouts"] == 0
    assert 25 < summary["device_rate_hz"] < 40  # the device clock still tells the frame period
    if summary["rate_hz"] is None:  # every frame came out of one read: one receive time
        assert summary["rate_note"].startswith("n/a (as fast as possible")
    assert main(["dump", "sim://?realtime=0", "--frames", "30"]) == 0
    last = capsys.readouterr().out.splitlines()[-1]
    assert "received at" in last and "received at n/a (device" not in last and "timeouts 0" in last


def test_the_preview_starts_at_the_first_contact_and_says_so(capsys):
    """issue 15: the simulated hand's session starts idle; fifty rows of zeros showed nothing."""
    assert main(["dump", "sim://?realtime=0", "--json"]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    notes = [x["text"] for x in lines if x["type"] == "note"]
    frames = [x for x in lines if x["type"] == "frame"]
    summary = lines[-1]
    assert len(frames) == 50 and frames[0]["max"] > 0
    assert summary["idle_frames_skipped"] > 0 and f"skipped {summary['idle_frames_skipped']} frames" in notes[-1]
    assert frames[0]["number"] == summary["idle_frames_skipped"]  # nothing lost, only not shown
    every = _summary(capsys, "sim://?realtime=0", "--all-frames")
    assert every["idle_frames_skipped"] == 0 and every["frames"] == 50


@pytest.mark.parametrize("url", ["tcp://", "tcp://h:1?bogus=1", "sim://?speed=fast", "tcp://[::1", "tcp://h:1/path",
                                 "sim://?speed=1&speed=2"])
def test_a_url_that_can_never_open_is_a_user_error_in_every_command(capsys, tmp_path, url):
    """docs/INTERFACES.md: exit 2 for what the user can fix; 1 is for a device that could not be reached."""
    for argv in (["dump", url], ["emulate", "--listen", url, "--duration", "1"],
                 ["record", "--device", url, "--subject", "s", "--out", str(tmp_path), "--auto"]):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"handover {argv[0]}: "), err


def test_a_refused_device_is_still_a_device_error(capsys):
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    assert main(["dump", f"tcp://127.0.0.1:{port}?connect_timeout=2"]) == 1
    assert "cannot connect" in capsys.readouterr().err


@pytest.mark.parametrize("seconds", ["-1", "0", "nan"])
def test_dump_refuses_seconds_that_are_not_positive(capsys, seconds):
    """NaN passed the check, streamed nothing and ended with a summary of 0 frames and exit 0."""
    with pytest.raises(SystemExit) as stop:  # argparse's type refuses it, before the device opens
        main(["dump", "sim://?speed=max", "--seconds", seconds])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"handover dump: argument --seconds: must be a positive number, got {seconds}")


@pytest.mark.parametrize("duration", ["-5", "0", "nan"])
def test_emulate_refuses_a_duration_that_is_not_positive(capsys, duration):
    with pytest.raises(SystemExit) as stop:  # argparse's type refuses it, before anything is served
        main(["emulate", "--pty", "--duration", duration])
    assert stop.value.code == 2
    assert "argument --duration: must be a positive number" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [["simulate", "--subjects", "1", "--runs", "1"],
                                  ["record", "--device", "subject://?speed=max", "--subject", "s", "--auto"]])
def test_an_output_folder_that_cannot_be_written_is_one_line_before_any_work(capsys, tmp_path, argv):
    (tmp_path / "file").write_text("")
    for out in (tmp_path / "file" / "x", tmp_path / "file"):  # the file named, also when --out is a folder inside it
        words = f"{tmp_path / 'file'} is a file, not a folder"
        assert main([*argv, "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"handover {argv[0]}: --out {out}: {words}"), err
        assert "choose a folder" in err[0]


def _pausing_device():
    """The emulator over TCP, pausing 1.5 s after every frame (a controller between streams)."""
    from firmware_io.emulator.device import DeviceEmulator, FaultPlan
    from firmware_io.emulator.frame_source import load_source
    from firmware_io.emulator.server import TcpEmulatorServer

    faults = FaultPlan(stall=1.0, stall_seconds=1.5)
    return TcpEmulatorServer(DeviceEmulator(load_source("sim", seed=0, events=2), speed=1.0, faults=faults)).start()


def test_a_count_of_frames_waits_through_a_pause_and_says_so_on_stderr(capsys):
    server = _pausing_device()
    try:
        code = main(["dump", server.url, "--frames", "2", "--all-frames", "--json"])
    finally:
        server.stop()
    out, err = capsys.readouterr()
    assert code == 0 and json.loads(out.splitlines()[-1])["frames"] == 2
    notes = err.splitlines()
    assert notes[0].startswith("handover dump: no frame for 1 s") and "waiting up to 10 s" in notes[0], err
    assert notes[1].startswith("handover dump: frames again after"), err


def test_a_pause_longer_than_timeout_stops_with_the_summary_and_one_line(capsys):
    server = _pausing_device()
    try:
        code = main(["dump", server.url, "--frames", "5", "--all-frames", "--timeout", "0.5", "--json"])
    finally:
        server.stop()
    out, err = capsys.readouterr()
    assert code == 1
    assert json.loads(out.splitlines()[-1])["frames"] == 1  # what came is still summed up
    assert len(err.splitlines()) == 1 and err.startswith("handover dump: no frame for 0.5 s, stopped"), err
    assert "--timeout S" in err


@pytest.mark.parametrize("timeout", ["0", "-1", "nan", "inf"])
def test_dump_refuses_a_timeout_that_is_not_a_positive_number(capsys, timeout):
    with pytest.raises(SystemExit) as stop:
        main(["dump", "sim://", "--frames", "1", "--timeout", timeout])
    assert stop.value.code == 2
    assert capsys.readouterr().err.startswith("handover dump: argument --timeout: must be a positive number")


def test_a_device_that_dies_mid_dump_still_gets_the_summary_of_what_came(capsys):
    from firmware_io.emulator.device import DeviceEmulator, FaultPlan
    from firmware_io.emulator.frame_source import load_source
    from firmware_io.emulator.server import TcpEmulatorServer

    device = DeviceEmulator(load_source("sim", seed=0, events=2), speed=None, faults=FaultPlan(disconnect_after=3))
    code, out, err, _url = _dump(capsys, TcpEmulatorServer(device), 50)
    assert code == 1
    assert json.loads(out.splitlines()[-1])["frames"] == 3  # the frames shown are summed up, not lost
    assert len(err.splitlines()) == 1 and "closed the connection" in err, err


def test_a_controller_that_boots_is_waited_for_and_said_on_stderr(capsys):
    """Right after another host left, an SDH-2 behind Ethernet resets and is deaf while it boots (8 s on the
    robot, 1.5 s here): dump said nothing meanwhile; it says what it waits for, once."""
    from firmware_io.emulator.device import DeviceEmulator
    from firmware_io.emulator.frame_source import load_source
    from firmware_io.emulator.server import TcpEmulatorServer

    emulator = DeviceEmulator(load_source("sim", seed=0, events=2), speed=1.0, boot_s=1.5, boot_query_s=1.2)
    emulator.power_cycle()
    code, out, err, url = _dump(capsys, TcpEmulatorServer(emulator), 2)
    assert code == 0 and json.loads(out.splitlines()[-1])["frames"] == 2
    waits = [line for line in err.splitlines() if "no answer yet" in line]
    assert len(waits) == 1 and waits[0].startswith(f"handover dump: {url}: no answer yet; waiting up to"), err


def _dump(capsys, server, frames: int) -> tuple[int, str, str, str]:
    """``handover dump URL --frames N --all-frames --json`` against ``server``: exit code, stdout, stderr, URL."""
    server.start()
    try:
        code = main(["dump", server.url, "--frames", str(frames), "--all-frames", "--json"])
    finally:
        server.stop()
    out, err = capsys.readouterr()
    return code, out, err, server.url


def test_a_boot_is_counted_apart_from_the_streams_errors():
    from firmware_io.commands.dump_cli import _errors

    said = _errors({"crc_errors": 1, "boot_queries": 3, "timeouts": 4})
    assert said == ("crc_errors 1, bad_headers 0, packets_dropped 0, bytes_dropped 0, decode_errors 0; "
                    "link: boot_queries 3, reconnects 0, timeouts 4")
