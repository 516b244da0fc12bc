"""The simulated hand: synthetic DSA 9205 frames of a person pulling, pushing, holding or
bumping an object the SDH-2 holds out (a virtual device, like python-can's virtual bus).

Physically motivated and calibrated against real SDH-2 recordings where they can measure
something (noise floor, value ranges, saturation, frame timing); see docs/SIMULATOR.md.
Everything it writes is synthetic data and says so in its meta. numpy only.
"""

from __future__ import annotations

from firmware_io.recording import ACTIONS
from firmware_io.sim.protocol import simulate_protocol, trial_counts, write_protocol
from firmware_io.sim.scenario import OBJECTS, POSES
from firmware_io.sim.session import ScriptedEvent, demo_script, simulate_session

__all__ = [
    "ACTIONS",
    "OBJECTS",
    "POSES",
    "ScriptedEvent",
    "demo_script",
    "simulate_protocol",
    "simulate_session",
    "trial_counts",
    "write_protocol",
]
