"""Cutting one trial out of the live stream: the held grasp before the go cue, then the action after it.

Every trigger the trainer may cut with needs the level before the action (the onset trigger its settled
grasp) and T frames after it: a trial is ``LEAD_IN_SECONDS`` before go plus ``seconds`` after, split by
when each frame arrived (frames queued when go is said belong to the lead-in). numpy only.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from firmware_io.errors import DeviceFailure

__all__ = ["LEAD_IN_SECONDS", "DeviceLost", "capture_trial", "drain"]

LEAD_IN_SECONDS = 1.0
"""Stream kept before the go cue: the held grasp. The onset trigger arms after 0.2 s without
change (``trigger.settle_s`` in runtime/config_keys.py); 1 s leaves room for a grasp still settling
when go is said, and for the window's pre_frames."""


class DeviceLost(DeviceFailure, RuntimeError):
    """The device went away and did not come back; everything recorded so far is saved."""


@dataclass
class Capture:
    """Frames of one trial; ``reconnected`` means the link dropped during it (the trial is void).

    ``go_frame``: the first frame that arrived after the go cue (the lead-in is the frames before it)."""

    frames: np.ndarray
    stamps: np.ndarray
    device_ms: np.ndarray
    reconnected: bool = False
    gaps: int = 0
    go_frame: int = 0
    received: np.ndarray | None = None
    """When each frame arrived (``time.perf_counter``): places the robot's messages on the frames."""


def drain(client, max_seconds: float = 0.25, fresh_wait: float = 0.005) -> int:
    """Throw away frames that arrived before the trial starts; returns how many.

    Queued and buffered frames come back at once; a frame we had to wait for is fresh, so the
    backlog is gone. A source that never makes us wait (an emulator at full speed) is drained
    for at most ``max_seconds``.
    """
    end = time.perf_counter() + max_seconds
    n = 0
    while time.perf_counter() < end:
        t = time.perf_counter()
        if client.read_frame(timeout=0.2) is None:
            break
        n += 1
        if time.perf_counter() - t >= fresh_wait:
            break
    return n


def capture_trial(client, seconds: float, frame_timeout: float = 2.0, lead_in: float = 0.0,
                  go: Callable[[], object] | None = None) -> Capture:
    """``lead_in`` s of frames before ``go()`` is called, then ``seconds`` after it (device time).

    Device time is the controller's clock, so any link speed works; a frame belongs to the
    lead-in when it arrived before ``go()`` returned. Timestamps are PC wall-clock seconds of the
    first kept frame plus device time since it: comparable across sessions and free of the host's
    scheduling jitter. Raises DeviceLost when no frame comes.
    """
    reconnects = client.stats.get("reconnects", 0)
    lead_ms, span_ms = lead_in * 1000.0, seconds * 1000.0
    kept: list = []  # frames, lead-in first
    go_at, go_index = (None, 0) if go is not None else (float("-inf"), 0)
    while True:
        frame = client.read_frame(timeout=frame_timeout)
        if frame is None:
            raise DeviceLost(f"{client.url}: no frame for {frame_timeout:g} s")
        if client.stats.get("reconnects", 0) != reconnects:
            dev = np.asarray([f.timestamp_ms for f in kept], np.int64)
            return Capture(_stack([f.values for f in kept], client), np.zeros(0), dev, reconnected=True)
        if go_at is None and kept and frame.timestamp_ms - kept[0].timestamp_ms >= lead_ms:
            go()
            go_at = time.perf_counter()
        if go_at is None or frame.received < go_at:  # before go: the held grasp, the newest lead_in s of it
            kept.append(frame)
            while kept[-1].timestamp_ms - kept[0].timestamp_ms > lead_ms:
                kept.pop(0)
            go_index = len(kept)
            continue
        if len(kept) > go_index and frame.timestamp_ms - kept[go_index].timestamp_ms >= span_ms:
            break
        kept.append(frame)
    return _capture(kept, go_index, seconds + lead_in, client)


def _capture(kept: list, go_index: int, seconds: float, client) -> Capture:
    dev = np.asarray([f.timestamp_ms for f in kept], dtype=np.int64)
    wall0 = time.time() - (time.perf_counter() - kept[0].received)
    rel = (dev - dev[0]) / 1000.0
    if len(rel) > 1 and not np.all(np.diff(rel) > 0):  # device clock unusable: fall back to spacing
        rel = np.arange(len(rel)) * (seconds / len(rel))
    steps = np.diff(dev)
    typical = float(np.median(steps)) if len(steps) else 0.0
    gaps = int(np.sum(steps > 2.5 * typical)) if typical > 0 else 0
    return Capture(_stack([f.values for f in kept], client), wall0 + rel, dev, gaps=gaps, go_frame=go_index,
                   received=np.asarray([f.received for f in kept], dtype=np.float64))


def _stack(frames: list, client) -> np.ndarray:
    n = client.layout.n_taxels if client.layout is not None else 0
    return np.asarray(frames, dtype=np.uint16) if frames else np.zeros((0, n), np.uint16)
