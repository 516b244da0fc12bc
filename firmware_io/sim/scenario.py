"""What is being simulated: objects, hand poses, subjects and the parameters of one trial.

All numbers here are assumed physical magnitudes (masses, sizes, forces, human movement
speeds), none fitted to anything; docs/SIMULATOR.md gives the reasoning.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from firmware_io.sim import constants as K

__all__ = [
    "FINGER_ANGLES", "OBJECTS", "OBJECT_MODELS", "POSES", "POSE_MODELS", "TrialSetup", "grasp_force", "half_widths",
    "make_subject", "make_trial", "pose_load"
]

OBJECTS = ("ball", "cylinder", "plank")
POSES = ("down", "up", "horizontal")

FINGER_ANGLES = np.radians([30.0, 180.0, -30.0])
"""Direction (in the palm plane) each finger presses from: fingers 0 and 2 side by side,
finger 1 (the SDH thumb) opposite them."""


@dataclass(frozen=True)
class ObjectModel:
    """Contact geometry and mass of a test object."""

    name: str
    mass_kg: float
    soft_mm: float  # edge softness of the patch (felt, cardboard, wood)
    hertz_mm: float  # contact half-width at 1 N (see ``half_widths``)
    width_mm: float  # fixed half-width across the pad for line/flat contacts (0: round)
    exponent: float  # half-width grows as force**exponent (Hertz: 1/3 sphere, 1/2 line)
    friction_mult: float  # object surface vs. the pad's friction
    rolls: bool


OBJECT_MODELS = {
    # tennis ball, 58 g: felt is soft, round Hertz contact a ~ F^(1/3); it rolls
    "ball": ObjectModel("ball", 0.058, 1.2, 3.2, 0.0, 1 / 3, 1.0, True),
    # cardboard tube: line contact across the (curved) pad, width ~ F^(1/2)
    "cylinder": ObjectModel("cylinder", 0.10, 0.6, 1.5, 8.0, 1 / 2, 0.9, False),
    # wooden plank: flat face, but the rounded finger pad limits the patch; torque bias
    "plank": ObjectModel("plank", 0.15, 0.4, 8.0, 6.5, 0.0, 0.8, False),
    # lab B's objects (firmware_io.sim.lab): a half-full 0.5 l plastic bottle, line contact on a
    # smooth wall; a kitchen sponge, light, very soft edges, a broad flat patch, grippy
    "bottle": ObjectModel("bottle", 0.30, 0.5, 1.8, 9.0, 1 / 2, 0.8, False),
    "sponge": ObjectModel("sponge", 0.02, 3.0, 9.0, 7.0, 0.0, 1.2, False),
}


def half_widths(obj: ObjectModel, force: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Contact half-widths (across x, along y) in mm for a normal force (N) per scan."""
    f = np.clip(force, 0.05, None)
    along = obj.hertz_mm * f**obj.exponent
    across = along if obj.width_mm == 0 else np.full_like(along, obj.width_mm)
    return across, along


@dataclass(frozen=True)
class PoseModel:
    """How gravity acts in the hand frame for a pose."""

    name: str
    in_plane: float  # fraction of the weight pressing in the palm plane
    in_plane_angle: float  # direction (rad) of that component
    outward: float  # fraction of the weight pulling the object out of the hand (+) or into it (-)


POSE_MODELS = {
    # fingers point down: the object hangs in the fingertips, pulled toward the tips
    "down": PoseModel("down", 0.0, 0.0, 1.0),
    # fingers point up: the object rests toward the palm
    "up": PoseModel("up", 0.0, 0.0, -1.0),
    # palm vertical, thumb underneath: the thumb carries the weight
    "horizontal": PoseModel("horizontal", 1.0, float(np.pi), 0.0),
}

GRASP_MIN_N = 0.5
GRASP_SAFETY = 1.5
"""assumed: a handover grasp is light (the robot must let go easily) but secure: per finger a
minimum plus a safety factor times the share of the weight friction must carry,
F = 0.5 N + 1.5 * m g / (3 mu). The paper's 15 % trigger, 'relatively low to avoid discarding
samples', implies the resting grasp mostly stayed below it."""


def grasp_force(obj: ObjectModel, friction: float) -> float:
    """Per-finger grasp force (N) the hand closes with on this object."""
    return GRASP_MIN_N + GRASP_SAFETY * obj.mass_kg * K.GRAVITY / (3.0 * friction)


def pose_load(pose: PoseModel, obj: ObjectModel) -> tuple[np.ndarray, float]:
    """Per-finger extra normal force (N) and contact shift along the pads (mm, + toward the palm).

    In-plane gravity presses the object into the fingers on that side (cosine share, half of
    it carried by friction). Outward gravity wedges the object into the curved fingertips
    (more normal force, contact toward the tip); inward lets it settle toward the palm.
    """
    w = obj.mass_kg * K.GRAVITY
    d_n = 0.5 * w * pose.in_plane * np.cos(pose.in_plane_angle - FINGER_ANGLES)
    d_n = d_n + 0.2 * w * pose.outward
    shift = -1.5 * pose.outward
    return d_n, shift


@dataclass(frozen=True)
class Subject:
    """How one person acts (the paper: students free to choose their own way)."""

    name: str
    strength: float  # multiplies forces
    speed: float  # multiplies movement speed
    reaction_s: float  # mean delay from the go signal to the action
    takes_out: float  # probability a pull takes the object out of the hand
    tremor_hz: float
    tremor_rel: float
    bump_angle: float  # preferred side to tap from (rad)


def make_subject(name: str, rng: np.random.Generator, strength: float = 1.0, speed: float = 1.0) -> Subject:
    """One person; ``strength`` and ``speed`` scale the draws (a lab's people, ``sim.lab``)."""
    return Subject(
        name=name,
        strength=float(rng.lognormal(0.0, 0.25)) * strength,
        speed=float(rng.lognormal(0.0, 0.2)) * speed,
        reaction_s=float(rng.uniform(0.5, 1.2)),
        takes_out=float(rng.uniform(0.3, 0.9)),
        tremor_hz=float(rng.uniform(8.0, 12.0)),
        tremor_rel=float(rng.uniform(0.01, 0.04)),
        bump_angle=float(rng.uniform(-np.pi, np.pi)),
    )


@dataclass(frozen=True)
class TrialSetup:
    """Everything fixed for one trial before the person acts."""

    subject: Subject
    obj: ObjectModel
    pose: PoseModel
    action: str
    onset_s: float  # action onset within the trial (seconds)
    strength: float  # this trial's strength (subject x trial-to-trial variation)
    speed: float
    grasp_force: np.ndarray  # [3] baseline normal force per finger (N)
    y0: np.ndarray  # [3] distal contact centre along the pad (mm from the tip)
    x0: np.ndarray  # [3] distal contact centre across the pad (mm)
    tilt: np.ndarray  # [3] torque bias of the patch (plank)
    friction: float  # effective friction coefficient (tape)
    taped: bool
    grasp_age_s: float  # how long the grasp has been held at trial start (creep)


def make_trial(subject: Subject, obj: ObjectModel, pose: PoseModel, action: str, duration: float,
               rng: np.random.Generator, taped: bool = True, onset_s: float | None = None,
               grip: float = 1.0) -> TrialSetup:
    """Draw one trial: the object's placement, this trial's variation, the onset; ``grip`` scales
    the hand's grasp force (a lab's controller setting, ``sim.lab``)."""
    d_n, shift = pose_load(pose, obj)
    friction = K.FRICTION_BARE * obj.friction_mult * (K.TAPE_FRICTION_FACTOR if taped else 1.0)
    grasp = grasp_force(obj, friction) * grip * rng.lognormal(0.0, 0.12, 3) + d_n
    if onset_s is None:
        onset_s = float(np.clip(subject.reaction_s + rng.normal(0.0, 0.15), 0.25, duration - 1.2))
    # the investigator places the object a little differently every run
    y_place = rng.uniform(14.0, 28.0)
    y0 = y_place + shift + rng.normal(0.0, 1.5, 3)
    x0 = 10.2 + rng.normal(0.0, 1.5, 3)
    tilt = rng.choice([-1.0, 1.0]) * rng.uniform(0.3, 0.9, 3) if obj.name == "plank" else np.zeros(3)
    return TrialSetup(
        subject=subject, obj=obj, pose=pose, action=action, onset_s=onset_s,
        strength=subject.strength * float(rng.lognormal(0.0, 0.15)),
        speed=subject.speed * float(rng.lognormal(0.0, 0.15)),
        grasp_force=np.clip(grasp, 0.2, None), y0=y0, x0=x0, tilt=tilt,
        friction=float(friction), taped=taped, grasp_age_s=float(rng.uniform(0.5, 2.0)),
    )
