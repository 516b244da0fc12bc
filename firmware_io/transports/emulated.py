"""In-process transports wired to the emulator core: ``sim://`` and ``replay://``.

The client talks to them exactly as to a serial port or a socket (bytes in, bytes out),
so the code path it exercises is the one it uses with a real controller; only the
byte link is missing.

- ``sim://?seed=0&events=40&realtime=1&loop=1&fault=...&old_firmware=0``: the simulated hand's
  scripted session (synthetic data). ``realtime=0`` sends frames as fast as they are read.
- ``replay://PATH?speed=1.0|max&loop=0&fault=...``: any recording (.hrec, .dsa, .bag).
  Without ``loop`` the transport raises EndOfStream once the last frame has been read.
"""

from __future__ import annotations

import time

from firmware_io.transports.base import (
    DEFAULT_READ_SIZE,
    MAX_EVENTS,
    DeviceUnavailable,
    EndOfStream,
    ParsedURL,
    Transport,
    TransportError,
    parse_bool,
    parse_number,
)

_COMMON = {"fault", "old_firmware", "loop", "start_ms"}


class EmulatedTransport(Transport):
    """A DeviceEmulator as a Transport: ``write`` feeds it, ``read`` waits for its output."""

    def __init__(self, emulator, url: str = "emulated://") -> None:
        self.url = url
        self.emulator = emulator
        self._closed = False
        emulator.connect()

    def write(self, data: bytes) -> None:
        self._check()
        self.emulator.feed(data)

    def read(self, max_bytes: int = DEFAULT_READ_SIZE, timeout: float = 0.1) -> bytes:
        self._check()
        emu = self.emulator
        deadline = time.monotonic() + max(timeout, 0.0)
        while True:
            data = emu.read(max_bytes)
            if data:
                return data
            if emu.disconnected:
                self._closed = True
                raise DeviceUnavailable(f"{self.url}: the emulated device dropped the link (fault injection)")
            if emu.finished:
                raise EndOfStream(f"{self.url}: end of the recording")
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return b""
            wait = emu.seconds_until_output()
            time.sleep(remaining if wait is None else min(max(wait, 0.0005), remaining))

    def close(self) -> None:
        self._closed = True

    def _check(self) -> None:
        if self._closed:
            raise TransportError(f"{self.url}: transport is closed")


def _emulator_options(parsed: ParsedURL, opts: dict) -> dict:
    from firmware_io.emulator.device import FaultPlan, FaultSpecError

    url = parsed.url
    try:
        faults = FaultPlan.parse(str(parsed.option(opts, "fault", "") or ""))
    except FaultSpecError as exc:
        raise TransportError(f"{url}: {exc}") from None
    return {
        "faults": faults,
        "old_firmware": parse_bool(url, "old_firmware", parsed.option(opts, "old_firmware", False)),
        "start_ms": int(parse_number(url, "start_ms", parsed.option(opts, "start_ms", 0), int, 0, 2**32 - 1)),
        "seed": int(parse_number(url, "seed", parsed.option(opts, "seed", 0), int, 0, 2**63 - 1)),
    }


def _parse_speed(url: str, text: object) -> float | None:
    if text is None or str(text).strip().lower() in ("max", "inf", "0"):
        return None
    return parse_number(url, "speed", text, float, 1e-6, 1e6)  # beyond: say "max"


def _build(parsed: ParsedURL, recording, speed: float | None, loop: bool, opts: dict) -> EmulatedTransport:
    from firmware_io.emulator.device import DeviceEmulator

    emulator = DeviceEmulator(recording, speed=speed, loop=loop, **_emulator_options(parsed, opts))
    return EmulatedTransport(emulator, parsed.url)


class SimTransport(EmulatedTransport):
    """``sim://``: the simulated hand."""

    @classmethod
    def from_url(cls, parsed: ParsedURL, **opts: object) -> EmulatedTransport:
        from firmware_io.emulator.frame_source import load_source
        from firmware_io.recordings.recording import RecordingError

        parsed.check_options(_COMMON | {"seed", "events", "realtime", "speed"})
        url = parsed.url
        seed = int(parse_number(url, "seed", parsed.option(opts, "seed", 0), int, 0, 2**63 - 1))
        events = int(parse_number(url, "events", parsed.option(opts, "events", 40), int, 1, MAX_EVENTS))
        realtime = parse_bool(url, "realtime", parsed.option(opts, "realtime", True))
        speed = _parse_speed(url, parsed.option(opts, "speed", 1.0)) if realtime else None
        loop = parse_bool(url, "loop", parsed.option(opts, "loop", True))
        try:
            recording = load_source("sim", seed=seed, events=events)
        except RecordingError as exc:
            raise TransportError(f"{url}: {exc}") from None
        return _build(parsed, recording, speed, loop, opts)


class ReplayTransport(EmulatedTransport):
    """``replay://PATH``: a recording file behind an emulated controller."""

    @classmethod
    def from_url(cls, parsed: ParsedURL, **opts: object) -> EmulatedTransport:
        from firmware_io.emulator.frame_source import load_source
        from firmware_io.recordings.recording import RecordingError

        parsed.check_options(_COMMON | {"speed", "seed"})
        url = parsed.url
        path = parsed.location
        if not path:
            raise TransportError(f"{url}: no file; use replay:///path/to/file.hrec")
        speed = _parse_speed(url, parsed.option(opts, "speed", 1.0))
        loop = parse_bool(url, "loop", parsed.option(opts, "loop", False))
        try:
            recording = load_source(path)
        except RecordingError as exc:
            raise DeviceUnavailable(f"{url}: {exc}") from None
        return _build(parsed, recording, speed, loop, opts)
