"""What the hand feels over time: the grasp baseline and the person's four actions.

Each function changes a :class:`Motion` (per finger: distal normal force and contact
position, proximal normal force and position) from the action's onset on. ``s`` is time since
the onset in seconds (negative before it). Forces in newtons, positions in mm along the pad
(row 0 at the fingertip end; + toward the palm) and across it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from firmware_io.sim.scenario import FINGER_ANGLES, TrialSetup, pose_load

__all__ = ["Motion", "baseline", "bump", "hold", "smooth", "trial_motion"]

PROXIMAL_ENTRY_MM = 5.0
"""Where on a proximal pad (from its distal end) an object pushed into the hand first lands."""


@dataclass
class Motion:
    """Contact state per finger ``[3, S]`` at scan rate."""

    nd: np.ndarray  # distal normal force
    yd: np.ndarray  # distal contact centre along the pad
    xd: np.ndarray  # distal contact centre across the pad
    np_: np.ndarray  # proximal normal force
    yp: np.ndarray  # proximal contact centre along the pad
    shear: np.ndarray  # tangential force on the distal pad along it (+ toward the palm)


def smooth(x: np.ndarray) -> np.ndarray:
    """0 -> 1 smoothstep (a human movement starts and ends gently)."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def baseline(setup: TrialSetup, t: np.ndarray, rng: np.random.Generator) -> Motion:
    """The held object: constant grasp force; a ball also rolls a little (slow random walk)."""
    n = len(t)
    nd = np.repeat(setup.grasp_force[:, None], n, axis=1)
    yd = np.repeat(setup.y0[:, None], n, axis=1)
    xd = np.repeat(setup.x0[:, None], n, axis=1)
    if setup.obj.rolls:
        step = rng.normal(0.0, 0.04, (2, n)).cumsum(axis=1)  # ~1 mm over 3 s
        yd = yd + step[0]
        xd = xd + step[1]
    weight = setup.obj.mass_kg * 9.81 * setup.pose.outward / 3.0  # carried by friction, toward the tip
    shear = np.full((3, n), -weight)
    return Motion(nd, yd, xd, np.zeros((3, n)), np.full((3, n), PROXIMAL_ENTRY_MM), shear)


def pull(m: Motion, setup: TrialSetup, s: np.ndarray, rng: np.random.Generator) -> None:
    """Object drawn out: shear, wedging into the curved tips, then sliding toward the tip.

    The pull force rises until it beats friction (lower with tape, so slip starts earlier);
    until then the rubber shears (contact centre shifts ~1 mm). Sliding moves the patch toward
    the tip; if the person takes the object, the patch leaves the pad and the force vanishes.
    """
    k, v = setup.strength, setup.speed
    ramp_s = 0.3 / v
    p_max = 4.0 * k
    friction_limit = setup.friction * float(np.sum(setup.grasp_force))
    frac = min(friction_limit / p_max, 0.95)
    slip_s = ramp_s * frac  # smoothstep ~ linear enough for the slip start
    pull_f = p_max * smooth(s / ramp_s)
    shear = np.minimum(pull_f / max(friction_limit, 1e-6), 1.0) * 1.0
    takes_out = rng.random() < setup.subject.takes_out
    accel = 400.0 * v * k  # mm/s^2
    ds = np.clip(s - slip_s, 0.0, None)
    d = 0.5 * accel * ds**2
    if takes_out:
        d = np.minimum(d, 0.5 * accel * 0.25**2 + 120.0 * v * np.clip(ds - 0.25, 0, None))
        leave = float(np.max(setup.y0)) + 6.0
        gone = 1.0 - smooth((d - leave * 0.6) / (leave * 0.6))
    else:
        stop = rng.uniform(4.0, 10.0)
        d = stop * (1.0 - np.exp(-d / stop))
        gone = np.ones_like(d)
    wedge = 1.0 + rng.uniform(0.5, 1.2) * k * smooth(s / ramp_s) * (1.0 - 0.6 * smooth(d / 8.0))
    m.nd *= wedge * gone
    m.yd -= shear + d
    m.shear -= np.minimum(pull_f / 3.0, setup.friction * m.nd)
    if setup.obj.rolls:
        m.xd += rng.normal(0.0, 0.15) * d


def push(m: Motion, setup: TrialSetup, s: np.ndarray, rng: np.random.Generator) -> None:
    """Object pushed into the palm: distal pads lose contact, proximal pads gain it.

    The object slides deeper where the finger gap widens, so the distal normal force first
    rises a little (pressed against friction) then fades; when it reaches the proximal links
    they take the push force. Subjects stop once the distal pads are free (paper).
    """
    k, v = setup.strength, setup.speed
    move_s = rng.uniform(0.4, 0.7) / v
    depth = rng.uniform(22.0, 32.0)
    d = depth * smooth(s / move_s)
    lose_at = rng.uniform(5.0, 9.0)
    press = 1.0 + 0.3 * k * smooth(s / (0.15 * move_s))
    m.nd *= press * (1.0 - smooth((d - lose_at) / rng.uniform(6.0, 10.0)))
    m.yd += d
    push_f = 2.0 * k * smooth(s / (0.3 * move_s))
    m.shear += np.minimum(push_f / 3.0, setup.friction * m.nd)
    reach = rng.uniform(12.0, 18.0)
    share = rng.lognormal(0.0, 0.2, 3)
    m.np_ += 2.5 * k * share[:, None] * smooth((d - reach) / 6.0)[None, :]
    m.yp += np.clip(d - reach, 0.0, None) * 0.6


def hold(m: Motion, setup: TrialSetup, s: np.ndarray, rng: np.random.Generator) -> None:
    """The person grips: slow changes, a small load shift, physiological tremor, damping.

    Taking over part of the weight removes some of the pose's gravity load; gripping presses
    the object a little toward one side; the hand adds 8-12 Hz tremor; the ball stops rolling.
    """
    k, v = setup.strength, setup.speed
    r = smooth(s / (rng.uniform(0.5, 0.9) / v))
    d_n, _ = pose_load(setup.pose, setup.obj)
    take_over = rng.uniform(0.3, 0.9)
    angle = rng.uniform(-np.pi, np.pi)
    squeeze = rng.uniform(0.2, 0.6) * k * np.cos(angle - FINGER_ANGLES)
    press = rng.uniform(0.2, 0.8) * k
    sub = setup.subject
    phase = rng.uniform(0, 2 * np.pi, 2)
    pos_s = np.clip(s, 0.0, None)
    tremor = sub.tremor_rel * (np.sin(2 * np.pi * sub.tremor_hz * pos_s + phase[0])
                               + 0.6 * np.sin(2 * np.pi * 1.3 * pos_s + phase[1]))
    m.nd += r[None, :] * (press + squeeze[:, None] - take_over * d_n[:, None])
    m.nd *= 1.0 + r[None, :] * tremor[None, :]
    m.shear *= 1.0 - take_over * r[None, :]
    if setup.obj.rolls:  # the hand damps the rolling: freeze the position at the onset
        i = int(np.searchsorted(s, 0.0))
        if i < m.yd.shape[1]:
            m.yd[:, i:] = m.yd[:, i:i + 1]
            m.xd[:, i:] = m.xd[:, i:i + 1]


def bump(m: Motion, setup: TrialSetup, s: np.ndarray, rng: np.random.Generator) -> None:
    """One tap: a short force pulse from one side, then a decaying oscillation, then baseline.

    The object on the compliant fingers rings at ~7-13 Hz, damped (zeta 0.15-0.3). The tap
    loads the fingers on the struck side and unloads the others; a ball may roll and stay.
    """
    k, v = setup.strength, setup.speed
    angle = setup.subject.bump_angle + rng.normal(0.0, 0.6)
    side = np.cos(angle - FINGER_ANGLES)
    width = rng.uniform(0.035, 0.07) / v
    amp = rng.uniform(2.0, 4.0) * k
    pos_s = np.clip(s, 0.0, None)
    pulse = np.where((s >= 0) & (s <= width), np.sin(np.pi * pos_s / width), 0.0)
    w = 2 * np.pi * rng.uniform(7.0, 13.0)
    zeta = rng.uniform(0.15, 0.3)
    ring = np.where(s > 0, np.exp(-zeta * w * pos_s) * np.sin(w * pos_s), 0.0)
    shape = pulse + 0.5 * ring
    m.nd += amp * (0.3 + side[:, None]) * shape[None, :]
    m.yd += 1.5 * side[:, None] * shape[None, :]
    m.shear += 0.3 * amp * np.sin(angle) * shape[None, :]
    if setup.obj.rolls:
        m.yd += rng.uniform(-1.0, 1.0) * smooth(s / (3 * width))[None, :]


ACTION_FUNCTIONS: dict[str, Callable[[Motion, TrialSetup, np.ndarray, np.random.Generator], None]] = {
    "pull": pull, "push": push, "hold": hold, "bump": bump,
}


def trial_motion(setup: TrialSetup, t: np.ndarray, rng: np.random.Generator,
                 grasp_window: tuple[float, float] | None = None) -> Motion:
    """Baseline plus the trial's action; ``grasp_window`` (close, open) ramps the grasp in/out."""
    m = baseline(setup, t, rng)
    ACTION_FUNCTIONS[setup.action](m, setup, t - setup.onset_s, rng)
    if grasp_window is not None:
        close, release = grasp_window
        env = smooth((t - close) / 0.3) * (1.0 - smooth((t - release) / 0.3))
        m.nd *= env[None, :]
        m.np_ *= env[None, :]
    np.clip(m.nd, 0.0, None, out=m.nd)
    np.clip(m.np_, 0.0, None, out=m.np_)
    return m
