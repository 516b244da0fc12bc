"""DSAClient against the emulated controller (``sim://``, in process) and a scripted device
for misbehaviour the emulator does not offer (silence, error replies, a device that never answers)."""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable

import numpy as np
import pytest

from firmware_io.client import Cancelled, DSAClient, DSATimeout, Frame
from firmware_io.layout import SensorLayout
from firmware_io.transports import DeviceUnavailable, Transport, TransportError
from firmware_io.wire.errors import DeviceError, DSAError, DSAErrorCode, ProtocolError
from firmware_io.wire.frames import encode_frame
from firmware_io.wire.packets import Packet, decode_packet, encode_ack
from firmware_io.wire.replies import ControllerInfo, MatrixInfoReply, SensorInfo, ThresholdReply

FAST = "sim://?seed=3&events=2&realtime=0"
QUICK = {"gap_timeout": 0.3, "stop_timeout": 0.3, "flush_max": 0.3, "flush_quiet": 0.05}


def sim_recording():
    from firmware_io.emulator.frame_source import load_source

    return load_source("sim", seed=3, events=2)


# -- against the emulator -------------------------------------------------------------------------
def test_open_builds_the_layout_from_the_controller() -> None:
    with DSAClient(FAST) as client:
        layout = client.layout
        assert layout is not None and layout.n_taxels == 486
        assert [(m.cells_x, m.cells_y) for m in layout.matrices] == [
            (m.cells_x, m.cells_y) for m in SensorLayout.sdh2().matrices
        ]
        assert client.controller.firmware == "2.9.0.0"
        assert client.sensor.nb_matrices == 6


def test_push_frames_match_the_source_bit_for_bit() -> None:
    rec = sim_recording()
    with DSAClient(FAST) as client:
        client.start()
        frames = [client.read_frame(2.0) for _ in range(40)]
        client.stop()
    assert all(isinstance(f, Frame) for f in frames)
    assert [f.number for f in frames] == list(range(40))
    for i, f in enumerate(frames):
        np.testing.assert_array_equal(f.values, rec.frames[i])
        assert f.values.dtype == np.uint16
    stamps = [f.timestamp_ms for f in frames]
    expected = np.round((rec.timestamps[:40] - rec.timestamps[0]) * 1000).astype(int)
    assert stamps == expected.tolist()
    assert all(b.received >= a.received for a, b in itertools.pairwise(frames))


def test_raw_frames_when_rle_is_off() -> None:
    rec = sim_recording()
    with DSAClient(FAST, rle=False) as client:
        client.start()
        f = client.read_frame(2.0)
    np.testing.assert_array_equal(f.values, rec.frames[0])


def test_newest_drops_stale_frames() -> None:
    with DSAClient(FAST) as client:
        client.start()
        time.sleep(0.05)
        first = client.read_frame(2.0)
        newest = client.read_frame(2.0, newest=True)
        assert newest.number > first.number + 1
        assert client.stats["frames_stale"] >= newest.number - first.number - 1


@pytest.mark.parametrize("old", [False, True])
def test_poll_frame_single_frames_and_old_firmware(old: bool) -> None:
    url = FAST + ("&old_firmware=1" if old else "")
    rec = sim_recording()
    with DSAClient(url, **QUICK) as client:
        assert client.controller.single_frame_broken == old
        a = client.poll_frame()
        b = client.poll_frame()
        np.testing.assert_array_equal(a.values, rec.frames[0])
        assert b.timestamp_ms > a.timestamp_ms
        # after the workaround nothing keeps arriving
        assert client.read_frame(0.2) is None
        assert not client._transport.emulator.pushing


def test_boot_query_and_faults_are_counted_and_frames_survive() -> None:
    url = FAST + "&fault=crc=0.05,garbage=0.05,drop=0.03,boot"
    with DSAClient(url) as client:
        client.start()
        frames = [client.read_frame(2.0) for _ in range(300)]
        emu = client._transport.emulator.stats
        stats = client.stats
    assert all(f is not None for f in frames)
    assert stats["boot_queries"] == 3
    assert stats["crc_errors"] >= emu.crc_corrupted > 0
    assert stats["bytes_dropped"] >= emu.garbage_bytes > 0
    numbers = [f.number for f in frames]
    assert numbers == sorted(numbers) and len(set(numbers)) == 300
    stamps = [f.timestamp_ms for f in frames]
    assert all(b > a for a, b in itertools.pairwise(stamps))


def test_timestamps_unwrap_across_the_u32_wrap() -> None:
    start = 2**32 - 300
    with DSAClient(FAST + f"&start_ms={start}") as client:
        client.start()
        stamps = [client.read_frame(2.0).timestamp_ms for _ in range(40)]
    assert stamps[0] == start
    assert stamps[-1] > 2**32
    assert all(b > a for a, b in itertools.pairwise(stamps))


def test_reconnect_after_disconnect_resumes_push() -> None:
    url = FAST + "&fault=disconnect=30"
    with DSAClient(url, backoff_initial=0.01) as client:
        client.start()
        frames = [client.read_frame(2.0) for _ in range(75)]
        assert client.stats["reconnects"] >= 2
        assert client.streaming
    assert all(f is not None for f in frames)
    assert [f.number for f in frames] == list(range(75))


def test_realtime_rate_is_about_32_hz() -> None:
    with DSAClient("sim://?seed=3&events=2") as client:
        client.start()
        t0 = time.monotonic()
        n = sum(client.read_frame(1.0) is not None for _ in range(12))
        elapsed = time.monotonic() - t0
    assert n == 12
    assert 0.2 < elapsed < 1.5  # synthetic stream at ~32 frames/s, loosely


def test_sensitivity_and_threshold_commands() -> None:
    with DSAClient(FAST, **QUICK) as client:
        client.set_threshold(1, 321)
        assert client.get_threshold(1) == 321
        client.set_sensitivity(2, 0.25)
        assert client.get_sensitivity(2).cur_sens == pytest.approx(0.25)
        with pytest.raises(DeviceError, match="INDEX_OUT_OF_BOUNDS"):
            client.get_threshold(9)


def test_bad_url_is_a_transport_error() -> None:
    with pytest.raises(TransportError):
        DSAClient("nope://x").open()


# -- a scripted device for misbehaviour --------------------------------------------------------
class ScriptedDevice(Transport):
    """Answers each request packet with whatever ``respond(packet)`` returns; can push frames."""

    def __init__(self, respond: Callable[[Packet], bytes], push: Callable[[], bytes] | None = None) -> None:
        self.url = "scripted://"
        self.respond = respond
        self.push = push
        self.out = bytearray()
        self.written: list[Packet] = []
        self._closed = False
        self.fail_reads = False
        self.timeouts: list[float] = []
        """The timeout of every read (how long the client let it block)."""

    def write(self, data: bytes) -> None:
        if self._closed:
            raise TransportError("closed")
        packet = decode_packet(data)
        self.written.append(packet)
        self.out += self.respond(packet)

    def read(self, max_bytes: int = 4096, timeout: float = 0.1) -> bytes:
        self.timeouts.append(timeout)
        if self._closed:
            raise TransportError("closed")
        if self.fail_reads:
            raise DeviceUnavailable("scripted://: connection closed by the device")
        if self.push is not None:
            self.out += self.push()
        if not self.out:
            time.sleep(min(timeout, 0.01))
            return b""
        data = bytes(self.out[:max_bytes])
        del self.out[:max_bytes]
        return data

    def close(self) -> None:
        self._closed = True


def good_device(packet: Packet, *, nb: int = 2, sensor_code: int = 0) -> bytes:
    pid = packet.packet_id
    if pid == 0x01:
        return ControllerInfo(sw_version=0x2900).to_packet()
    if pid == 0x02:
        if sensor_code:
            return encode_ack(0x02, sensor_code)
        return SensorInfo(nb_matrices=nb).to_packet()
    if pid == 0x0B:
        return MatrixInfoReply(cells_x=3, cells_y=4).to_packet()
    if pid == 0x03:
        return encode_ack(0x03)
    return b""


def test_scripted_open_and_error_code_checked_in_every_reply() -> None:
    dev = ScriptedDevice(good_device)
    client = DSAClient(dev, **QUICK)
    assert client.open().n_taxels == 24
    assert [p.packet_id for p in dev.written] == [0x03, 0x01, 0x02, 0x0B, 0x0B]
    assert dev.written[0].payload == b"\x01\x00\x00"  # stop, RLE flag, rate 0
    dev2 = ScriptedDevice(lambda p: good_device(p, sensor_code=DSAErrorCode.NO_SENSOR))
    with pytest.raises(DeviceError, match="E_NO_SENSOR"):
        DSAClient(dev2, **QUICK).open()
    dev3 = ScriptedDevice(lambda p: good_device(p, nb=0))
    with pytest.raises(ProtocolError, match="no tactile matrices"):
        DSAClient(dev3, **QUICK).open()


def test_silent_device_open_is_bounded_and_close_never_hangs() -> None:
    dev = ScriptedDevice(lambda p: b"")
    client = DSAClient(dev, open_timeout=2.0, **QUICK)
    t0 = time.monotonic()
    with pytest.raises(DSATimeout):
        client.open()
    # stop tried until the open's deadline (a booting controller is deaf for 8 s), then one bounded query
    assert time.monotonic() - t0 < 2.0 + 0.3 + 0.5
    assert sum(p.packet_id == 0x03 for p in dev.written) >= 5
    assert client.stats["timeouts"] >= 4
    t0 = time.monotonic()
    client.close()
    client.close()
    assert time.monotonic() - t0 < 1.5
    assert dev.closed


def test_at_most_four_frames_skipped_waiting_for_a_reply_and_they_are_queued() -> None:
    counter = iter(range(10**6))

    def push() -> bytes:
        return encode_frame(np.full(24, 7, np.uint16), next(counter), rle=True)

    dev = ScriptedDevice(good_device)
    client = DSAClient(dev, **QUICK)
    client.open()
    dev.push = push  # the device now pushes frames and never answers 0x14
    with pytest.raises(DSATimeout, match="within 4 frames"):
        client.get_threshold(0)
    dev.push = None
    frames = [client.read_frame(0.2) for _ in range(5)]
    assert all(f is not None for f in frames)
    assert [f.timestamp_ms for f in frames] == list(range(5))


def test_transport_failure_on_a_given_transport_is_raised() -> None:
    dev = ScriptedDevice(good_device)
    client = DSAClient(dev, **QUICK)
    client.open()
    dev.fail_reads = True
    with pytest.raises(TransportError):
        client.read_frame(0.5)


def test_reconnect_backs_off_exponentially_and_gives_up() -> None:
    attempts: list[float] = []

    def factory() -> Transport:
        attempts.append(time.monotonic())
        raise DeviceUnavailable("scripted://: no device")

    client = DSAClient(factory, reconnect_tries=4, backoff_initial=0.05, backoff_max=1.0, **QUICK)
    with pytest.raises(TransportError, match=r"^the device: reconnect failed after 4 tries"):
        client.reconnect()
    gaps = np.diff(attempts)
    assert len(attempts) == 4
    assert gaps[0] >= 0.05 and gaps[1] >= 0.1 and gaps[2] >= 0.2


def test_a_factorys_device_keeps_its_name_once_its_transport_is_dropped() -> None:
    dev = ScriptedDevice(good_device)
    client = DSAClient(lambda: dev, **QUICK)
    client.open()
    client._drop_transport()
    assert client.url == dev.url and client.url != "None", "messages after a drop named the device 'None'"


def test_reconnect_through_a_factory_recovers() -> None:
    made: list[ScriptedDevice] = []

    def factory() -> Transport:
        if len(made) == 1:
            made.append(None)  # type: ignore[arg-type]
            raise DeviceUnavailable("scripted://: not yet")
        dev = ScriptedDevice(good_device)
        made.append(dev)
        return dev

    client = DSAClient(factory, backoff_initial=0.01, **QUICK)
    client.open()
    made[0].fail_reads = True
    assert client.read_frame(0.3) is None  # reconnected, then no frame (not pushing)
    assert client.stats["reconnects"] == 1
    assert len(made) == 3


def test_a_corrupt_length_before_a_reply_is_released_after_a_gap() -> None:
    """The reply hidden behind a header whose length asks for more bytes than ever come."""

    def respond(packet: Packet) -> bytes:
        if packet.packet_id == 0x14:
            bad = bytearray(ThresholdReply(5).to_packet())
            bad[4:6] = b"\x30\x00"  # plausible (48) but wrong
            return bytes(bad) + ThresholdReply(77).to_packet()
        return good_device(packet)

    client = DSAClient(ScriptedDevice(respond), **QUICK)
    client.open()
    assert client.get_threshold(0) == 77
    assert client.stats["bytes_dropped"] > 0


def test_partial_frame_survives_a_short_read_timeout() -> None:
    frame = encode_frame(np.arange(24, dtype=np.uint16), 42, rle=False)
    dev = ScriptedDevice(good_device)
    client = DSAClient(dev, **QUICK)
    client.open()
    dev.out += frame[:20]
    assert client.read_frame(0.02) is None
    dev.out += frame[20:]
    f = client.read_frame(0.2)
    assert f is not None and f.timestamp_ms == 42
    np.testing.assert_array_equal(f.values, np.arange(24))


def test_a_zero_timeout_polls_once_without_blocking_or_counting_a_timeout() -> None:
    """``read_frame(0)``: a poll (a caller that must not block, e.g. between two other duties)."""
    frame = encode_frame(np.arange(24, dtype=np.uint16), 7, rle=False)
    dev = ScriptedDevice(good_device)
    client = DSAClient(dev, **QUICK)
    client.open()
    before = client.stats["timeouts"]
    dev.timeouts.clear()
    assert client.read_frame(0) is None
    assert dev.timeouts and max(dev.timeouts) == 0  # the link was never asked to wait
    dev.out += frame[:20]
    assert client.read_frame(0) is None  # half a frame waits in the parser
    dev.out += frame[20:]
    f = client.read_frame(0)
    assert f is not None and f.timestamp_ms == 7 and client.stats["timeouts"] == before


class _Chunks(Transport):
    """A link that hands over one queued chunk per read (nothing waiting: b"") and counts the reads."""

    def __init__(self, chunks: list[bytes]) -> None:
        self.chunks, self.reads = chunks, 0

    def read(self, max_bytes: int = 0, timeout: float = 0.1) -> bytes:
        self.reads += 1
        return self.chunks.pop(0) if self.chunks else b""

    def write(self, data: bytes) -> None:
        pass

    def close(self) -> None:
        pass


def test_a_poll_returns_the_first_frame_of_a_burst_without_parsing_the_rest() -> None:
    """A due frame with more queued behind it (a burst after a stall): the poll hands over the first
    frame after one read, and the rest wait in the transport for the next reads, none lost."""
    layout = SensorLayout.sdh2()
    values = np.zeros(layout.n_taxels, dtype=np.uint16)
    link = _Chunks([encode_frame(values, t, rle=True) for t in range(5)])
    client = DSAClient.already_streaming(link, layout)
    first = client.read_frame(0)
    assert first is not None and first.timestamp_ms == 0 and link.reads == 1
    rest = [client.read_frame(0) for _ in range(4)]
    assert [f.timestamp_ms for f in rest] == [1, 2, 3, 4] and client.read_frame(0) is None


def test_replies_a_streaming_device_sends_between_frames_do_not_pile_up() -> None:
    """Non-frame packets while streaming (a confused or rebooting device answering nothing asked) are
    read between frames and no command waits for them: frames all come through, in order, and the
    queue of replies stays bounded instead of growing for as long as the device keeps sending them."""
    from firmware_io.client import MAX_QUEUED_REPLIES

    layout = SensorLayout.sdh2()
    values = np.zeros(layout.n_taxels, dtype=np.uint16)
    stray = encode_ack(0x01)
    link = _Chunks([stray * 50 + encode_frame(values, t, rle=True) for t in range(200)])
    client = DSAClient.already_streaming(link, layout)
    got = [client.read_frame(0) for _ in range(200)]
    assert [f.timestamp_ms for f in got] == list(range(200))
    assert len(client._replies) <= MAX_QUEUED_REPLIES


def test_bytes_a_poll_took_in_are_not_given_up_as_a_silent_line() -> None:
    """A caller polls a frame in, then blocks on the next one: a poll that took in a frame and
    the start of the next (one USB packet or TCP segment holding both) leaves that start pending. The
    next blocking read that finds nothing yet must not take the line for silent for a gap timeout (the
    last bytes came a moment ago, in the poll) and drop the start: the next frame would be lost."""
    layout = SensorLayout.sdh2()
    values = np.zeros(layout.n_taxels, dtype=np.uint16)
    first, second = (encode_frame(values, t, rle=True) for t in (1, 2))
    half = len(second) // 2
    link = _Chunks([first + second[:half], b"", second[half:]])
    client = DSAClient.already_streaming(link, layout, gap_timeout=0.5)
    assert client.read_frame(0).timestamp_ms == 1
    frame = client.read_frame(0.05)  # its first read finds nothing yet, the next one the rest
    assert frame is not None and frame.timestamp_ms == 2
    assert client.stats["bytes_dropped"] == 0


def test_close_then_open_again_on_the_same_client() -> None:
    """What the daemon does after a fault: close, later open() the same client again."""
    client = DSAClient(FAST)
    client.open()
    client.start()
    assert client.read_frame(2.0) is not None
    client.close()
    with pytest.raises(DSAError, match="open"):
        client.read_frame(0.1)
    assert client.open().n_taxels == 486
    client.start()
    assert client.read_frame(2.0) is not None
    client.close()


def test_open_of_a_silent_device_is_cancelled_by_the_callers_predicate() -> None:
    """The default timeouts (1 s gap, 3 stop tries) make a silent open last ~5 s; a service
    stopping meanwhile must not wait for that."""
    dev = ScriptedDevice(lambda p: b"")
    client = DSAClient(dev)  # the real timeouts
    asked: list[float] = []
    t0 = time.monotonic()

    def should_stop() -> bool:
        asked.append(time.monotonic() - t0)
        return asked[-1] > 0.3

    with pytest.raises(Cancelled):
        client.open(should_stop=should_stop)
    took = time.monotonic() - t0
    assert took < 0.3 + 0.2, took
    assert max(np.diff([0.0, *asked])) < 0.1  # asked between reads, at least every 50 ms (+ slack)
    t1 = time.monotonic()
    client.close()  # the transport was dropped: no stop handshake with a device that never answers
    assert time.monotonic() - t1 < 0.05
    with pytest.raises(DSAError, match="open"):
        client.read_frame(0.01)


def test_start_is_cancellable_and_close_bounds_the_stop_handshake() -> None:
    dev = ScriptedDevice(good_device)
    client = DSAClient(dev)
    client.open(should_stop=lambda: False)  # a predicate that never fires changes nothing
    dev.respond = lambda p: b""  # the controller hangs
    with pytest.raises(Cancelled):
        client.start(should_stop=lambda: True)
    client2 = DSAClient(ScriptedDevice(good_device))
    client2.open()
    client2._transport.respond = lambda p: b""
    t0 = time.monotonic()
    client2.close(stop_timeout=0.1)
    assert time.monotonic() - t0 < 0.3
