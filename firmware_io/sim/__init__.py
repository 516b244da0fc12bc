"""The simulated hand: synthetic DSA 9205 frames of a person pulling, pushing, holding or
bumping an object the SDH-2 holds out (a virtual device, like python-can's virtual bus).

Physically motivated and calibrated against real SDH-2 recordings where they can measure
something (noise floor, value ranges, saturation, frame timing); see docs/SIMULATOR.md.
Everything it writes is synthetic data and says so in its meta. numpy only.

This package's names below are its public face; its modules are the parts, one per physical
effect: ``constants`` (measured figures), ``streams`` (seeded substreams), ``contact``
(pressure patches on the pads), ``sensor`` (DSA 9205 transduction and the DSACON32m
firmware), ``timing`` (PC time stamps), ``scenario`` (objects, poses, subjects, trial
parameters), ``actions`` (what the person does), ``hand`` (renders trials into frames),
``paper_protocol`` (the paper's recording protocol) and ``session`` (a free-running session),
``idle`` (streams nobody touches). Beside them: ``scripted_subject`` (a simulated person
behind an emulated controller, for ``handover record``) and ``realism`` (statistics that
compare the simulator's output with real recordings).
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
