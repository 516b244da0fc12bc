"""The simulated hand: synthetic DSA 9205 frames of a person acting on an object the SDH-2 holds out.

Calibrated against real SDH-2 recordings where they can measure something (docs/SIMULATOR.md); its
output says it is synthetic in its meta. One module per physical effect; numpy only.
"""

from __future__ import annotations

from firmware_io.recordings.recording import ACTIONS
from firmware_io.sim.paper_protocol import simulate_protocol, trial_counts, write_protocol
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
