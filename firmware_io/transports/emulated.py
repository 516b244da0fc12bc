"""In-process transports wired to the emulator core: ``sim://``, ``replay://`` and ``subject://``.

The client talks to them as to a serial port, so it exercises the code path of a real controller;
URL options: ``firmware_io.transports`` and docs/EMULATOR.md. A ``replay://`` without ``loop`` raises
EndOfStream after the last frame.
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
    parse_speed,
)

__all__ = ["SUBJECT_SCHEME", "EmulatedTransport", "ReplayTransport", "SimTransport", "SubjectTransport"]

_COMMON = {"fault", "old_firmware", "loop", "start_ms"}
SUBJECT_SCHEME = "subject"


class EmulatedTransport(Transport):
    """A DeviceEmulator as a Transport: ``write`` feeds it, ``read`` waits for its output."""

    def __init__(self, emulator, url: str = "emulated://") -> None:
        self.url = url
        self.emulator = emulator
        self._closed = False
        emulator.connect()

    def write(self, data: bytes) -> None:
        self._check_open()
        self.emulator.feed(data)

    def read(self, max_bytes: int = DEFAULT_READ_SIZE, timeout: float = 0.1) -> bytes:
        self._check_open()
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


def _fault_plan(parsed: ParsedURL, opts: dict):
    from firmware_io.emulator.device import FaultPlan, FaultSpecError

    try:
        return FaultPlan.parse(str(parsed.option(opts, "fault", "") or ""))
    except FaultSpecError as exc:
        raise TransportError(f"{parsed.url}: {exc}") from None


def _no_location(parsed: ParsedURL) -> None:
    """``sim://`` and ``subject://`` run in process: a host or path would be silently ignored."""
    if parsed.location not in ("", "/"):
        raise TransportError(f"{parsed.url}: {parsed.scheme}:// takes no location ({parsed.location[:40]!r}); "
                             f"use {parsed.scheme}://?option=value")


def _seed(parsed: ParsedURL, opts: dict) -> int:
    return int(parse_number(parsed.url, "seed", parsed.option(opts, "seed", 0), int, 0, 2**63 - 1))


def _lab(parsed: ParsedURL, opts: dict):
    """The ``lab=`` option: which simulated lab's hand and people (``firmware_io.sim.lab``), default A."""
    from firmware_io.sim.lab import UnknownLab, get_lab

    try:
        return get_lab(parsed.option(opts, "lab"))
    except UnknownLab as exc:
        raise TransportError(f"{parsed.url}: {exc}") from None


def _emulator_settings(parsed: ParsedURL, opts: dict, allowed: set[str], loop: bool) -> dict:
    """The options every emulated controller takes: the DeviceEmulator's keyword arguments."""
    parsed.check_options(_COMMON | allowed)
    url = parsed.url
    return {
        "faults": _fault_plan(parsed, opts),
        "old_firmware": parse_bool(url, "old_firmware", parsed.option(opts, "old_firmware", False)),
        "start_ms": int(parse_number(url, "start_ms", parsed.option(opts, "start_ms", 0), int, 0, 2**32 - 1)),
        "seed": _seed(parsed, opts),
        "loop": parse_bool(url, "loop", parsed.option(opts, "loop", loop)),
        "speed": parse_speed(url, parsed.option(opts, "speed", 1.0)),
    }


def _build(parsed: ParsedURL, recording, emulator_settings: dict) -> EmulatedTransport:
    from firmware_io.emulator.device import DeviceEmulator

    return EmulatedTransport(DeviceEmulator(recording, **emulator_settings), parsed.url)


class SimTransport(EmulatedTransport):
    """``sim://``: the simulated hand."""

    @classmethod
    def url_settings(cls, parsed: ParsedURL, opts: dict) -> dict:
        _no_location(parsed)
        emulator = _emulator_settings(parsed, opts, {"seed", "events", "realtime", "speed", "lab"}, loop=True)
        events = int(parse_number(parsed.url, "events", parsed.option(opts, "events", 40), int, 1, MAX_EVENTS))
        if not parse_bool(parsed.url, "realtime", parsed.option(opts, "realtime", True)):
            emulator["speed"] = None
        return {"events": events, "lab": _lab(parsed, opts).name, "emulator": emulator}

    @classmethod
    def from_url(cls, parsed: ParsedURL, **opts: object) -> EmulatedTransport:
        from firmware_io.emulator.frame_source import load_source
        from firmware_io.recordings.recording import RecordingError

        settings = cls.url_settings(parsed, opts)
        try:
            recording = load_source("sim", seed=settings["emulator"]["seed"], events=settings["events"],
                                    lab=settings["lab"])
        except RecordingError as exc:
            raise TransportError(f"{parsed.url}: {exc}") from None
        return _build(parsed, recording, settings["emulator"])


class ReplayTransport(EmulatedTransport):
    """``replay://PATH``: a recording file behind an emulated controller."""

    @classmethod
    def url_settings(cls, parsed: ParsedURL, opts: dict) -> dict:
        emulator = _emulator_settings(parsed, opts, {"speed", "seed"}, loop=False)
        if not parsed.location:
            raise TransportError(f"{parsed.url}: no file; use replay:///path/to/file.hrec")
        return {"path": parsed.location, "emulator": emulator}

    @classmethod
    def from_url(cls, parsed: ParsedURL, **opts: object) -> EmulatedTransport:
        from firmware_io.emulator.frame_source import load_source
        from firmware_io.recordings.recording import RecordingError

        settings = cls.url_settings(parsed, opts)
        try:
            recording = load_source(settings["path"])
        except RecordingError as exc:
            raise DeviceUnavailable(f"{parsed.url}: {exc}") from None
        return _build(parsed, recording, settings["emulator"])


class SubjectTransport(EmulatedTransport):
    """``subject://``: a scripted simulated subject behind an emulated controller (synthetic data).

    Opened by URL it is a subject nobody prompts (an idle hand); ``handover record`` builds the
    subject from the same settings and prompts it (``ScriptedSubject.from_url``).
    """

    @classmethod
    def url_settings(cls, parsed: ParsedURL, opts: dict) -> dict:
        """The ScriptedSubject's keyword arguments."""
        _no_location(parsed)
        parsed.check_options({"seed", "lab", "speed", "drop", "unplug", "unplug_idle", "lazy", "fault", "seconds"})
        url = parsed.url
        unplug = _frame_numbers(parsed, opts, "unplug")
        return {
            "seed": _seed(parsed, opts),
            "lab": _lab(parsed, opts),
            "speed": parse_speed(url, parsed.option(opts, "speed", 1.0)),
            "faults": _fault_plan(parsed, opts),
            "drop_at": _frame_numbers(parsed, opts, "drop"),
            "unplug_at": unplug[0] if unplug else None,
            "unplug_idle": int(parse_number(url, "unplug_idle", parsed.option(opts, "unplug_idle", 0), int, 0, 2**31 - 1)),
            "lazy": _frame_numbers(parsed, opts, "lazy"),
            "trial_seconds": parse_number(url, "seconds", parsed.option(opts, "seconds", 3.0), float, 0.0, 3600.0),
        }

    @classmethod
    def from_url(cls, parsed: ParsedURL, **opts: object) -> Transport:
        from firmware_io.sim.scripted_subject import ScriptedSubject

        return ScriptedSubject(**cls.url_settings(parsed, opts)).connect()


def _frame_numbers(parsed: ParsedURL, opts: dict, name: str) -> list[int]:
    """A comma-separated list of counts (``drop=300,900``)."""
    text = str(parsed.option(opts, name, "") or "")
    return [int(parse_number(parsed.url, name, v, int, 0, 2**31 - 1)) for v in text.split(",") if v.strip()]
