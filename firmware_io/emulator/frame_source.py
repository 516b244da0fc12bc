"""Where an emulated controller's frames come from: the simulated hand or a recording file.

``load_source("sim", seed=DEMO_SESSION_SEED, events=40)`` is the simulated hand's scripted session
(synthetic data; by default the demo's, which no demo model trains on); any other text is a recording path (.hrec, .dsa, .bag, ROS 2 bag folder).
Results are cached per (source, seed, events, file mtime) so that reconnecting to a
``sim://`` or ``replay://`` transport does not simulate or decode the session again.
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

import numpy as np

from firmware_io.frame_timing import NOMINAL_RATE_HZ
from firmware_io.layout import SensorLayout
from firmware_io.recordings.importers import import_any
from firmware_io.recordings.recording import Recording, RecordingError
from firmware_io.sim.session import DEMO_SESSION_SEED

__all__ = ["load_source", "placeholder_session"]

SIM = "sim"


def load_source(source: str | os.PathLike = SIM, *, seed: int = DEMO_SESSION_SEED, events: int = 40,
                lab: str | None = None) -> Recording:
    """A Recording to serve (``lab``: the simulated lab, ``firmware_io.sim.lab``); raises RecordingError
    with one line naming the file or the problem."""
    text = os.fspath(source)
    if text == SIM:
        return _simulated(int(seed), int(events), lab)
    path = Path(text).expanduser()
    try:
        mtime = path.stat().st_mtime_ns
    except FileNotFoundError:
        raise RecordingError(f"{path}: no such file or folder") from None
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read ({exc.strerror})") from None
    return _from_file(str(path.resolve()), mtime)


@lru_cache(maxsize=4)
def _from_file(path: str, mtime_ns: int) -> Recording:

    rec = import_any(path)
    if rec.n_frames == 0:
        raise RecordingError(f"{path}: the recording has no frames to serve")
    return rec


@lru_cache(maxsize=4)
def _simulated(seed: int, events: int, lab: str | None = None) -> Recording:
    if events < 1:
        raise RecordingError(f"the simulated session needs at least one event, got {events}")
    try:
        from firmware_io.sim import demo_script, simulate_session
        from firmware_io.sim.lab import get_lab
    except ImportError:
        return placeholder_session(seed, events)
    lab_ = get_lab(lab)
    return simulate_session(demo_script(n_events=events, seed=seed, objects=lab_.objects), seed=seed, lab=lab_)


def placeholder_session(seed: int = 0, events: int = 4, rate_hz: float = NOMINAL_RATE_HZ) -> Recording:
    """Synthetic stand-in used only while ``firmware_io.sim`` is absent: a noisy blob per event.

    Not a model of a hand; it exists so that the emulator has deterministic frames to send.
    """
    layout = SensorLayout.sdh2()
    rng = np.random.default_rng(seed)
    n = int(rate_hz * (2.0 + 4.0 * events))
    frames = rng.integers(0, 3, size=(n, layout.n_taxels)).astype(np.uint16)
    distal = layout.columns("distal")
    for e in range(events):
        start = int(rate_hz * (2.0 + 4.0 * e))
        span = np.arange(start, min(n, start + int(rate_hz * 1.5)))
        level = (np.sin(np.linspace(0, np.pi, len(span))) * rng.uniform(800, 2500)).astype(np.uint16)
        frames[np.ix_(span, distal[:40])] += level[:, None]
    frames &= 0x0FFF
    frames[:, ~layout.static_mask()] = 0
    stamps = np.arange(n) / rate_hz
    return Recording(layout, frames, stamps, [], {"synthetic": True, "source": "placeholder_session", "seed": seed})
