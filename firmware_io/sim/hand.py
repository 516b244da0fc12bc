"""Render trials into frames: motion -> pressure on each pad -> sensor -> firmware frames.

Trials are rendered in chunks so every numpy operation covers many thousand scans at once
(fast) while memory stays bounded by the chunk.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from firmware_io.sim import constants as K
from firmware_io.sim.actions import Motion, trial_motion
from firmware_io.sim.contact import blur_width, pad_pressure
from firmware_io.sim.scenario import TrialSetup, half_widths
from firmware_io.sim.sensor import HandSensor, average_scans, firmware_output, response

__all__ = ["CREEP_GAIN", "CREEP_TAU_S", "SCAN_PERIOD_S", "Job", "creep", "render", "shear_tilt"]

SCAN_PERIOD_S = K.FRAME_PERIOD_S / K.SCANS_PER_FRAME
CHUNK_SCANS = 20000

CREEP_GAIN = 0.10
CREEP_TAU_S = 4.0
"""measured (roughly): under a constant grasp the readings keep rising (grasp_shere.dsa: peak
1825 -> 2297 over ~7 s), viscoelastic creep of the rubber: ~+10 % with a few seconds' constant."""


@dataclass(frozen=True)
class Job:
    """One segment to render: its setup, length in frames, random stream, optional grasp window."""

    setup: TrialSetup
    n_frames: int
    rng: np.random.Generator
    grasp_window: tuple[float, float] | None = None


def creep(t: np.ndarray, age_s: float) -> np.ndarray:
    """Reading gain of a pad loaded since ``age_s`` before ``t = 0`` (viscoelastic creep)."""
    return 1.0 + CREEP_GAIN * (1.0 - np.exp(-(t + age_s) / CREEP_TAU_S))


SHEAR_TILT = 0.8
"""assumed: a tangential load tilts the pressure under a soft pad toward its leading edge
(moment balance of the shear acting above the surface); tilt ~ 0.8 x shear / normal force."""


def shear_tilt(static_tilt: float, shear: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Torque bias of the patch: the object's own (plank) plus the shear's, limited to +-1.5."""
    return np.clip(static_tilt + SHEAR_TILT * shear / np.maximum(normal, 0.2), -1.5, 1.5)


def _pad_inputs(job: Job, m: Motion, finger: int, distal: bool, t: np.ndarray) -> dict:
    setup = job.setup
    force = (m.nd if distal else m.np_)[finger] * creep(t, setup.grasp_age_s if distal else 0.0)
    wx, wy = half_widths(setup.obj, force)
    n = len(t)
    return {
        "force": force,
        "cx": m.xd[finger] if distal else np.full(n, setup.x0[finger]),
        "cy": m.yd[finger] if distal else m.yp[finger],
        "wx": wx,
        "wy": wy,
        "sigma": np.full(n, float(blur_width(setup.obj.soft_mm, setup.taped))),
        "tilt": shear_tilt(setup.tilt[finger], m.shear[finger], m.nd[finger]) if distal else np.zeros(n),
    }


def _render_chunk(jobs: Sequence[Job], sensor: HandSensor) -> list[np.ndarray]:
    layout = sensor.layout
    per_pad: dict[int, list[dict]] = {i: [] for i in range(layout.n_matrices)}
    for job in jobs:
        t = (np.arange(job.n_frames * K.SCANS_PER_FRAME) + 0.5) * SCAN_PERIOD_S
        m = trial_motion(job.setup, t, job.rng, job.grasp_window)
        for pad in range(layout.n_matrices):
            per_pad[pad].append(_pad_inputs(job, m, pad // 2, pad % 2 == 1, t))
    n_scans = sum(j.n_frames for j in jobs) * K.SCANS_PER_FRAME
    signal = np.empty((n_scans // K.SCANS_PER_FRAME, layout.n_taxels), dtype=np.float32)
    for pad, parts in per_pad.items():
        args = {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}
        mat = layout.matrices[pad]
        kpa = pad_pressure(mat.cells_x, mat.cells_y, **args).reshape(n_scans, -1)
        cols = layout.matrix_slice(pad)
        counts = response(kpa, sensor.gain[cols], sensor.ceiling[cols])
        signal[:, cols] = average_scans(counts)
    out, pos = [], 0
    for job in jobs:
        out.append(firmware_output(signal[pos:pos + job.n_frames], sensor, job.rng))
        pos += job.n_frames
    return out


def render(jobs: Sequence[Job], sensor: HandSensor) -> list[np.ndarray]:
    """uint16 frames ``[n_frames, C]`` for each job, in order."""
    out: list[np.ndarray] = []
    chunk: list[Job] = []
    size = 0
    for job in jobs:
        chunk.append(job)
        size += job.n_frames * K.SCANS_PER_FRAME
        if size >= CHUNK_SCANS:
            out.extend(_render_chunk(chunk, sensor))
            chunk, size = [], 0
    if chunk:
        out.extend(_render_chunk(chunk, sensor))
    return out
