"""Transports by URL: parsing and errors, missing optional packages, TCP EOF, and the pyusb and
hidapi transports run against emulated bridges (pyusb backend object, hid.device stand-in)."""

from __future__ import annotations

import contextlib
import re
import socket
import sys
import threading
import time

import numpy as np
import pytest

from firmware_io.client import DSAClient
from firmware_io.emulator.device import DeviceEmulator
from firmware_io.emulator.frame_source import placeholder_session
from firmware_io.emulator.links import EmulatedCp2110, EmulatedUsbBackend
from firmware_io.layout import SensorLayout
from firmware_io.transports import (
    DeviceUnavailable,
    MissingDependency,
    Transport,
    TransportError,
    open_transport,
    validate_url,
)
from firmware_io.transports.emulated import EmulatedTransport
from firmware_io.transports.hid import data_reports, uart_config_report
from firmware_io.transports.usb import ftdi_baud_divisor, strip_ftdi_status


@pytest.fixture(scope="module")
def rec():
    return placeholder_session(seed=2, events=1)


@pytest.mark.parametrize(
    ("url", "words"),
    [
        ("", "empty device URL"),
        ("foo://x", "unknown scheme 'foo://'"),
        ("ttyUSB0", "no scheme"),
        ("usb://xyz", "VID:PID"),
        ("usb://0403", "VID:PID"),
        ("usb://12345:1", "16-bit"),
        ("hid://10c4:ea80:1", "VID:PID"),
        ("tcp://", "no host"),
        ("tcp://host:99999", "port 1..65535"),
        ("sim://?seed=x", "seed='x' is not an integer"),
        ("sim://?bogus=1", "unknown option 'bogus'"),
        ("sim://?fault=crc=5", "fault"),
        ("replay://", "no file"),
        ("subject://?sped=2", "unknown option 'sped'"),
        ("subject://?speed=nan", "speed='nan' must be a finite number"),
        ("subject://?unplug=soon", "unplug='soon' is not an integer"),
        ("sim://?speed=2e7", "speed=20000000.0 must be at most"),
    ],
)
def test_bad_urls_give_one_clear_error(url, words):
    with pytest.raises(TransportError) as info:
        open_transport(url)
    assert words in str(info.value)
    assert "\n" not in str(info.value)


def test_missing_devices_are_device_unavailable(tmp_path):
    with pytest.raises(DeviceUnavailable, match="cannot open serial port") as info:
        open_transport("/dev/tty-does-not-exist")
    assert "does not exist (hand's USB cable plugged in?" in str(info.value)  # says what to check
    assert "\n" not in str(info.value)
    with pytest.raises(DeviceUnavailable, match="no such file"):
        open_transport(f"replay://{tmp_path}/none.hrec")
    (tmp_path / "file").write_text("")
    for not_a_tty in ("/dev/null", str(tmp_path), str(tmp_path / "file")):  # pyserial's bare "Inappropriate ioctl" said nothing useful
        with pytest.raises(DeviceUnavailable, match=f"{not_a_tty} is not a serial port; use .* e.g. /dev/ttyUSB0"):
            open_transport(f"serial://{not_a_tty}")
    with socket.socket() as s:  # a free port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(DeviceUnavailable, match=r"cannot connect: .*\(hand powered, host and port right\?"):
        open_transport(f"tcp://127.0.0.1:{port}?connect_timeout=1")


def test_missing_optional_packages_name_the_extra(monkeypatch):
    for name in ("usb", "usb.core", "usb.util"):
        monkeypatch.setitem(sys.modules, name, None)
    monkeypatch.setitem(sys.modules, "hid", None)
    with pytest.raises(MissingDependency, match=r"tactile-handover\[usb\]"):
        open_transport("usb://0403:6001")
    with pytest.raises(MissingDependency, match=r"tactile-handover\[usb\]"):
        open_transport("hid://10c4:ea80")


def test_missing_libusb_backend_is_explained():
    import usb.backend.libusb1

    if usb.backend.libusb1.get_backend() is not None:
        pytest.skip("libusb is installed here; the message is for machines without it")
    with pytest.raises(MissingDependency, match=r"libusb-1\.0"):
        open_transport("usb://0403:6001")


def test_subject_scheme_goes_through_the_registry():
    """subject:// is a scheme like any other: checked by its transport, opened by URL (an idle subject)."""
    from firmware_io.sim.scripted_subject import ScriptedSubject
    from firmware_io.transports import TRANSPORTS, validate_url

    assert "subject" in TRANSPORTS
    assert validate_url("subject://?seed=4&speed=max&lazy=1,2").scheme == "subject"
    subject = ScriptedSubject.from_url("subject://?seed=4&speed=0&drop=5,7&unplug=40&lazy=2&seconds=2")
    assert (subject.seed, subject.emulator.speed, subject.drop_at, subject.unplug_at, subject.lazy) == (
        4, None, {5, 7}, 40, {2})
    client = DSAClient("subject://?seed=4&speed=max", auto_reconnect=False)
    try:
        assert client.open().n_taxels == SensorLayout.sdh2().n_taxels
        client.start()
        frame = client.read_frame(timeout=2.0)
        assert frame is not None and int(frame.values.max()) == 0  # nobody prompts it: an empty hand
    finally:
        client.close()


@pytest.mark.parametrize(("text", "speed"), [("max", None), ("INF", None), ("0", None), (None, None), ("2.5", 2.5),
                                             (1, 1.0)])
def test_speed_is_read_one_way(text, speed):
    from firmware_io.transports.base import parse_speed

    assert parse_speed("x://", text) == speed


def test_tcp_eof_is_device_unavailable():
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    port = server.getsockname()[1]

    def accept_and_close():
        conn, _ = server.accept()
        conn.sendall(b"\x01\x02")
        conn.close()

    thread = threading.Thread(target=accept_and_close, daemon=True)
    thread.start()
    try:
        with open_transport(f"tcp://127.0.0.1:{port}") as t:
            assert t._sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY)
            got = b""
            with pytest.raises(DeviceUnavailable, match="closed the connection"):
                for _ in range(20):
                    got += t.read(100, 1.0)
            assert got == b"\x01\x02"
    finally:
        thread.join(2)
        server.close()


@pytest.mark.parametrize("scheme", ["serial:///dev/ttyUSB0", "usb://0403:6001", "hid://10c4:ea80"])
def test_every_bridge_reads_baud_one_way(scheme):
    from firmware_io.transports.base import DEFAULT_BAUD, ParsedURL, parse_baud

    assert parse_baud(ParsedURL(scheme), {}) == DEFAULT_BAUD == 115200
    assert parse_baud(ParsedURL(f"{scheme}?baud=9600"), {}) == 9600
    assert parse_baud(ParsedURL(f"{scheme}?baud=9600"), {"baud": 57600}) == 57600  # a keyword option wins
    for bad in ("0", "12000001", "fast"):
        with pytest.raises(TransportError, match=f"option baud='?{bad}'? "):
            validate_url(f"{scheme}?baud={bad}")


@pytest.mark.parametrize("scheme", ["usb", "hid"])
def test_usb_bridges_read_vid_pid_serial_and_baud_one_way(scheme):
    from firmware_io.transports.base import ParsedURL, parse_bridge

    assert parse_bridge(ParsedURL(f"{scheme}://10c4:EA80?serial="), {}) == {
        "vid": 0x10C4, "pid": 0xEA80, "serial": None, "baud": 115200}
    assert parse_bridge(ParsedURL(f"{scheme}://0403:6001?serial=A1&baud=9600"), {"serial": "B2"})["serial"] == "B2"
    with pytest.raises(TransportError, match="expected VID:PID"):
        validate_url(f"{scheme}://0403")

def test_bridge_helpers():
    assert ftdi_baud_divisor(115200) == (26, 0)
    assert ftdi_baud_divisor(9600) == (0x4138, 0)  # 312.5 -> 312 + 4/8 (code 1 -> bit 14)
    assert strip_ftdi_status(b"\x01\x60", 64) == b""
    data = b"\x01\x60" + bytes(range(62)) + b"\x01\x60abc"
    assert strip_ftdi_status(data, 64) == bytes(range(62)) + b"abc"
    assert uart_config_report(115200) == b"\x50\x00\x01\xc2\x00\x00\x00\x03\x00"
    reports = data_reports(bytes(range(130)))
    assert [r[0] for r in reports] == [63, 63, 4] and b"".join(r[1:] for r in reports) == bytes(range(130))


def _check_client(transport, rec, n=12):
    client = DSAClient(transport, gap_timeout=0.5, stop_timeout=1.0, flush_quiet=0.05)
    layout = client.open()
    sdh2 = SensorLayout.sdh2()
    assert [(m.cells_x, m.cells_y, m.center) for m in layout.matrices] == [
        (m.cells_x, m.cells_y, m.center) for m in sdh2.matrices
    ]
    client.start()
    frames = [client.read_frame(timeout=2.0) for _ in range(n)]
    assert all(f is not None for f in frames)
    for i, f in enumerate(frames):
        assert np.array_equal(f.values, rec.frames[i])
    client.close()
    return client


@pytest.mark.parametrize(
    ("chip", "vid", "expected"),
    [
        ("ftdi", 0x0403, [(0x40, 0x00, 0, 1), (0x40, 0x03, 26, 0), (0x40, 0x04, 8, 1), (0x40, 0x02, 0, 1),
                          (0x40, 0x09, 2, 1)]),
        ("cdc", 0x2341, [(0x21, 0x20, 0, 0), (0x21, 0x22, 3, 0)]),
        ("cp210x", 0x10C4, [(0x41, 0x00, 1, 0), (0x41, 0x1E, 0, 0), (0x41, 0x03, 0x0800, 0)]),
    ],
)
def test_usb_transport_through_emulated_pyusb_backend(rec, chip, vid, expected):
    backend = EmulatedUsbBackend(DeviceEmulator(rec, speed=None), vid=vid, pid=0x6001, chip=chip)
    transport = open_transport(f"usb://{vid:04x}:6001?serial=DSA00001", backend=backend)
    assert transport.chip == chip
    assert [r[:4] for r in backend.control_requests] == expected
    if chip == "cdc":
        assert backend.control_requests[0][4] == b"\x00\xc2\x01\x00\x00\x00\x08"  # 115200, 1 stop, none, 8
        assert sorted(backend.detached) == [0, 1]
    if chip == "cp210x":
        assert backend.control_requests[1][4] == (115200).to_bytes(4, "little")
    assert backend.claimed
    _check_client(transport, rec)
    assert backend.detached == [] and backend.claimed == set()  # kernel driver back, interface released


def test_usb_transport_reads_one_packet_at_a_time(rec):
    """pyusb drops whatever a timed-out transfer had received, so a transfer longer than one packet
    that times out while a frame streams in (a poll, read timeout 0, waits libusb's shortest
    timeout, 1 ms; a blocking read with a few ms left) loses its full packets. A one-packet transfer
    ends with the first packet: nothing to lose. Every read, polled or blocking, asks one packet."""
    backend = EmulatedUsbBackend(DeviceEmulator(rec, speed=None))
    t = open_transport("usb://0403:6001", backend=backend)
    before = len(backend.read_sizes)
    t.read(4096, 0.0)
    t.read(4096, 0.05)
    t.read(16384, 1.0)
    assert set(backend.read_sizes[before:]) == {EmulatedUsbBackend.PACKET}
    t.close()


def _short_packet_wait(backend: EmulatedUsbBackend) -> float:
    """Seconds an emulated bridge takes to hand over 10 bytes that do not fill a packet."""
    import array

    backend._held = bytes(10)  # the emulator stands idle: bytes put in the chip by hand
    buff = array.array("B", bytes(64))
    t0 = time.monotonic()
    n = backend.bulk_read(None, 0x81, 0, buff, 2000)
    assert n == 12 and bytes(buff[:2]) == b"\x01\x60"  # status bytes, then the 10
    return time.monotonic() - t0


def test_the_emulated_ftdi_chip_holds_a_short_packet_until_its_latency_timer_runs_out(rec):
    """An FTDI chip sends a packet that is not full when its latency timer (16 ms after reset) runs
    out: a frame's last packet came up to 16 ms late, half the sample period. The transport sets the
    timer to 1 ms, and the emulated chip honours it (wide margins: this is about the model of the
    chip, not the machine's speed)."""
    backend = EmulatedUsbBackend(DeviceEmulator(rec, speed=None))
    backend.latency_ms = 250
    assert _short_packet_wait(backend) >= 0.2
    t = open_transport("usb://0403:6001", backend=backend)
    assert backend.latency_ms == 2  # the transport's default (FTDI_LATENCY_MS: CPU against delay)
    assert _short_packet_wait(backend) < 0.15
    t.close()
    t = open_transport("usb://0403:6001?latency=1", backend=backend)
    assert backend.latency_ms == 1
    t.close()


def test_an_idle_ftdi_chip_answers_its_status_bytes_at_each_latency_period(rec):
    """With nothing to send the chip answers two status bytes when its timer runs out (every 16 ms
    by default), not only when the host's read times out."""
    import array

    backend = EmulatedUsbBackend(DeviceEmulator(rec, speed=None))
    buff = array.array("B", bytes(64))
    t0 = time.monotonic()
    assert backend.bulk_read(None, 0x81, 0, buff, 5000) == 2 and bytes(buff[:2]) == b"\x01\x60"
    assert time.monotonic() - t0 < 2.0  # the 16 ms timer, not the 5 s read timeout


def _stale_reply_in_the_chip(backend: EmulatedUsbBackend) -> bytes:
    """A controller-info reply the chip took from the UART and still holds: the host's read timed
    out before the latency timer (16 ms after reset) let the short packet go."""
    import array

    from usb.core import USBTimeoutError

    from firmware_io.wire import requests as R

    backend.bulk_write(None, 0x02, 0, R.query_controller_info_request(), 1000)
    with pytest.raises(USBTimeoutError):
        backend.bulk_read(None, 0x81, 0, array.array("B", bytes(64)), 2)
    assert backend._held  # kept for the next read, as the chip does
    return backend._held


def test_a_reset_or_replugged_ftdi_chip_hands_no_stale_bytes_to_the_next_session(rec):
    """SIO_RESET (sent when the transport opens) purges the chip's buffers, and an unplugged chip
    loses them with its power (and its latency timer goes back to 16 ms): the bytes a timed-out read
    left in the emulated chip were handed to the next session instead."""
    backend = EmulatedUsbBackend(DeviceEmulator(rec, speed=None))
    _stale_reply_in_the_chip(backend)
    t = open_transport("usb://0403:6001", backend=backend)
    assert t.read(64, 0.05) == b""
    t.close()

    backend.latency_ms = 16  # as a host that set nothing would leave it
    _stale_reply_in_the_chip(backend)
    backend.unplugged = True
    backend.replug()
    assert (backend._held, backend.latency_ms, backend.unplugged) == (b"", 16, False)
    t = open_transport("usb://0403:6001", backend=backend)
    assert t.read(64, 0.05) == b""
    t.close()


def test_usb_transport_errors(rec):
    backend = EmulatedUsbBackend(DeviceEmulator(rec, speed=None))
    with pytest.raises(DeviceUnavailable, match="serial 'other'"):
        open_transport("usb://0403:6001?serial=other", backend=backend)
    with pytest.raises(DeviceUnavailable, match="no USB device 0403:6002"):
        open_transport("usb://0403:6002", backend=backend)
    with pytest.raises(TransportError, match="no interface 3"):
        open_transport("usb://0403:6001?interface=3", backend=backend)
    for bad in ("0", "256", "fast"):
        with pytest.raises(TransportError, match=f"option latency={bad!r}|option latency={bad} must"):
            open_transport(f"usb://0403:6001?latency={bad}", backend=backend)
    for other in ("0403:6001?chip=cdc&latency=5", "0403:6001?chip=cp210x&latency=1", "10c4:ea60?latency=2"):
        with pytest.raises(TransportError, match="latency= sets an FTDI chip's latency timer and this is a"):
            open_transport(f"usb://{other}", backend=backend)  # was silently ignored
    t = open_transport("usb://0403:6001", backend=backend)
    assert t.read(64, 0.05) == b""  # idle FTDI: status bytes only
    backend.unplugged = True
    with pytest.raises(DeviceUnavailable, match="device gone"):
        t.read(64, 0.05)
    t.close()


def test_hid_transport_through_cp2110_stand_in(rec):
    device = EmulatedCp2110(DeviceEmulator(rec, speed=None))
    transport = open_transport("hid://10c4:ea80", device=device)
    assert device.uart_config == (115200, 0, 0, 3, 0) and device.uart_enabled
    assert [r[0] for r in device.feature_reports] == [0x50, 0x41, 0x43]
    _check_client(transport, rec)
    assert not device.is_open


def test_hid_transport_polls_without_waiting_for_a_report(rec):
    """hidapi's read with timeout 0 blocks until the next report unless the device is non-blocking:
    a poll (read timeout 0) must come back at once on a quiet line."""
    device = EmulatedCp2110(DeviceEmulator(rec, speed=None))
    t = open_transport("hid://10c4:ea80", device=device)
    assert t.read(10, 0.0) == b""
    assert not device.blocking  # a blocking hidapi read would wait for the next report
    t.close()


def test_hid_transport_errors(rec):
    device = EmulatedCp2110(DeviceEmulator(rec, speed=None))
    with pytest.raises(DeviceUnavailable, match="cannot open HID device 10c4:ea81"):
        open_transport("hid://10c4:ea81", device=device)
    t = open_transport("hid://10c4:ea80", device=device)
    assert t.read(10, 0.02) == b""
    device.unplugged = True
    with pytest.raises(DeviceUnavailable, match=r"hid://10c4:ea80: read failed \(unplugged\?\): "):
        t.read(10, 0.02)
    with pytest.raises(DeviceUnavailable, match=r"hid://10c4:ea80: write failed \(unplugged\?\): "):
        t.write(b"\x01")
    with pytest.raises(DeviceUnavailable, match=r"hid://10c4:ea80: feature report 0x41 failed: "):
        t._feature(bytes([0x41, 1]))



def _open_emulated(kind: str, rec):
    emulator = DeviceEmulator(rec, speed=None)
    if kind == "hid":
        return open_transport("hid://10c4:ea80", device=EmulatedCp2110(emulator))
    if kind == "usb":
        return open_transport("usb://0403:6001", backend=EmulatedUsbBackend(emulator))
    return EmulatedTransport(emulator)


@pytest.mark.parametrize("kind", ["hid", "usb", "emulated"])
def test_a_closed_transport_refuses_reads_and_writes_with_one_line_and_closes_twice_harmlessly(kind, rec):
    t = _open_emulated(kind, rec)
    t.close()
    t.close()
    assert t.closed
    for call in (lambda: t.read(10, 0.0), lambda: t.write(b"x")):
        with pytest.raises(TransportError, match=r": transport is closed$"):
            call()


def test_close_releases_the_device_once():
    class Counting(Transport):
        released = 0
        _closed = False

        def write(self, data: bytes) -> None:
            self._check_open()

        def read(self, max_bytes: int = 4096, timeout: float = 0.1) -> bytes:
            self._check_open()
            return b""

        def _release(self) -> None:
            self.released += 1

    t = Counting()
    t.close()
    t.close()
    assert t.released == 1

_VALID = {"serial": "serial:///dev/ttyUSB0?baud=115200", "tcp": "tcp://192.168.1.42:13000?connect_timeout=3",
          "usb": "usb://0403:6001?serial=A1&baud=115200", "hid": "hid://10c4:ea80?baud=115200",
          "sim": "sim://?seed=0&events=4", "replay": "replay:///tmp/x.hrec?speed=max",
          "subject": "subject://?seed=1&speed=max"}
_ALWAYS_REFUSED = ["[::1", "]x:1", "[x", "[::", "[zz]:1", "[]:1", "h\x00:1", "\x00", "a\nb?x=1", "x\u2028y",
                   "?a=1&a=1", "?=&&", "x?%00=1", "?seed=1&seed=2", "0403:6001?baud=1&baud=1"]
_HOSTILE = ["[", "]", "%", "%zz", "%00", "%ff", "\x00", "\n", "\u2028", "\u0661", "é", ":", "::", "@", "#", "?",
            "&", "=", "/", "\\", " ", "9" * 30, "-1", "1e999", "nan", "", "ß" * 70]


@pytest.mark.parametrize("scheme", sorted(_VALID))
def test_malformed_urls_of_every_scheme_are_always_the_url_error(scheme):
    """Whatever the URL, checking it gives a ParsedURL or one TransportError line, never another exception
    (a ValueError from urlsplit once killed a running daemon on SIGHUP)."""
    import random

    from firmware_io.transports import validate_url

    def one_line_error_or_ok(url: str) -> bool:
        try:
            validate_url(url)
        except MissingDependency:
            return True
        except TransportError as exc:
            assert len(str(exc).splitlines()) == 1, repr(str(exc))
            return False
        return True

    for tail in _ALWAYS_REFUSED:
        assert not one_line_error_or_ok(f"{scheme}://{tail}"), tail
    rng = random.Random(scheme)
    valid = _VALID[scheme]
    for _ in range(400):
        url = list(valid)
        for _ in range(rng.randint(1, 3)):
            at = rng.randrange(len("scheme://") - 2, len(url) + 1)
            url[at:at + rng.randint(0, 3)] = rng.choice(_HOSTILE)
        one_line_error_or_ok("".join(url))


@pytest.mark.parametrize(("url", "words"), [
    ("tcp://h:1/path", "a tcp URL has no path"),
    ("tcp://[::1]:x", "port 1..65535, got 'x'"),
    ("tcp://u@h:1", "is not a host name"),
    ("tcp://a..b", "is not a valid host name"),
    ("sim://?speed=1&speed=2", "option 'speed' given 2 times; give it once"),
    ("sim://host?seed=1", "sim:// takes no location"),
    ("tcp://[::1", "write an IPv6 host as tcp://[::1]:13000"),
    ("tcp://[zz]:1", "cannot read the location"),
])
def test_url_mistakes_found_by_a_stranger_are_refused(url, words):
    from firmware_io.transports import validate_url

    with pytest.raises(TransportError, match=re.escape(words)):
        validate_url(url)


def test_well_formed_urls_still_pass():
    from firmware_io.transports import validate_url

    for url in [*_VALID.values(), "tcp://[::1]", "tcp://[fe80::1%eth0]:13000", "tcp://händ.local:1", "sim:///",
                "/dev/ttyUSB0", "COM3"]:
        with contextlib.suppress(MissingDependency):  # usb:// and hid:// without the extra
            validate_url(url)


@pytest.mark.parametrize(("url", "words"), [
    ("usb://0403:6001?serial=%00", "option 'serial' decodes to the unprintable character '\\x00'"),
    ("hid://10c4:ea80?serial=A%0A%1B[31m", "option 'serial' decodes to the unprintable character '\\n'"),
    ("usb://0403:6001?chip=%7F", "option 'chip' decodes to the unprintable character '\\x7f'"),
    ("usb://-0:6001", "VID:PID must be hexadecimal"),
    ("usb://0x403:0x6001", "VID:PID must be hexadecimal"),
    ("hid://04_03:+601", "VID:PID must be hexadecimal"),
    ("hid://\u0661\u0660c4:ea80", "VID:PID must be hexadecimal"),
    ("usb://0403:6001?baud=" + "9" * 5000, "a device URL of 5021 characters; write one of at most 4096"),
    ("serial:///dev/" + "x" * 100_000, "a device URL of 100014 characters"),
])
def test_bridge_urls_a_hostile_world_writes_are_one_short_line(url, words):
    """A serial number decoded from %00 or %0A reached hidapi and pyusb (and the config check passed it);
    int(..., 16) read -0, 0x403 and Arabic-Indic digits as a VID; a megabyte URL was a megabyte line, twice."""
    from firmware_io.transports import validate_url

    with pytest.raises(TransportError) as info:
        validate_url(url)
    line = str(info.value)
    assert words in line and "\n" not in line and len(line) < 300


def _close_right_after_the_check(t: Transport) -> None:
    """``close`` from another thread between the closed check and the device call (the race, made certain)."""
    real = t._check_open
    first = [True]

    def check() -> None:
        real()
        if first[0]:
            first[0] = False
            t.close()

    t._check_open = check


@contextlib.contextmanager
def _opened(kind: str, rec):
    if kind in ("hid", "usb"):
        with _open_emulated(kind, rec) as t:
            yield t
    elif kind == "tcp":
        with socket.create_server(("127.0.0.1", 0)) as server:
            t = open_transport(f"tcp://127.0.0.1:{server.getsockname()[1]}")
            peer, _ = server.accept()
            with peer, t:
                yield t
    else:
        import os

        leader, follower = os.openpty()
        try:
            with open_transport(f"serial://{os.ttyname(follower)}?exclusive=0") as t:
                yield t
        finally:
            os.close(leader)
            os.close(follower)


@pytest.mark.parametrize("call", ["read", "write"])
@pytest.mark.parametrize("kind", ["tcp", "serial", "hid", "usb"])
def test_close_from_another_thread_during_a_call_is_the_closed_line(kind, call, rec):
    """A close while a read waited in select: tcp raised ValueError (select on fd -1) or said the device had
    hung up, blaming another client; serial and the bridges said the device was unplugged."""
    with _opened(kind, rec) as t:
        _close_right_after_the_check(t)
        with pytest.raises(TransportError, match=r": transport is closed$"):
            t.read(64, 0.05) if call == "read" else t.write(b"x" * 64)


def test_a_tcp_read_waiting_when_another_thread_closes_ends_with_the_closed_line():
    with socket.create_server(("127.0.0.1", 0)) as server:
        t = open_transport(f"tcp://127.0.0.1:{server.getsockname()[1]}")
        peer, _ = server.accept()
        outcome: list[BaseException] = []

        def read() -> None:
            try:
                t.read(64, 30.0)
            except TransportError as exc:
                outcome.append(exc)

        reader = threading.Thread(target=read)
        with peer:
            reader.start()
            t.close()
            reader.join(30.0)
    assert not reader.is_alive() and str(outcome[0]).endswith(": transport is closed")


def test_a_baud_the_bridge_cannot_do_is_the_urls_error():
    """It passed run --check and failed at every reconnect of the daemon as a device error, retried forever."""
    from firmware_io.transports import validate_url

    for url in ("usb://0403:6001?baud=100", "usb://0403:6001?baud=3000001", "usb://1234:5678?chip=ftdi&baud=100"):
        with pytest.raises(TransportError, match=r"outside what an FTDI bridge can do \(183\.\.3000000\)") as info:
            validate_url(url)
        assert str(info.value).startswith(url + ": ")
    for url in ("usb://0403:6001?baud=3000000", "usb://0403:6001?chip=cdc&baud=100", "usb://10c4:ea60?baud=100",
                "hid://10c4:ea80?baud=300", "hid://10c4:ea80?baud=1000000"):
        validate_url(url)
    for url in ("hid://10c4:ea80?baud=299", "hid://10c4:ea80?baud=1000001"):
        with pytest.raises(TransportError, match=r"outside what a CP2110 bridge can do \(300\.\.1000000\)"):
            validate_url(url)


def test_a_connect_the_kernel_gave_up_on_does_not_claim_the_urls_timeout(monkeypatch):
    """connect_timeout=3600 and a silent host: the kernel's ETIMEDOUT came after about 2 minutes and the line
    said 'no answer within 3600 s'."""
    import errno

    from firmware_io.transports import tcp

    def kernel_gave_up(address, timeout):
        raise TimeoutError(errno.ETIMEDOUT, "Connection timed out")

    monkeypatch.setattr(tcp.socket, "create_connection", kernel_gave_up)
    with pytest.raises(DeviceUnavailable) as info:
        open_transport("tcp://192.0.2.7:13000?connect_timeout=3600")
    assert str(info.value).endswith(": no answer (Connection timed out) (hand powered? cable?)")

    def python_timeout(address, timeout):
        raise TimeoutError("timed out")

    monkeypatch.setattr(tcp.socket, "create_connection", python_timeout)
    with pytest.raises(DeviceUnavailable, match=r": no answer within 3 s \(hand powered\? cable\?\)$"):
        open_transport("tcp://192.0.2.7:13000?connect_timeout=3")
