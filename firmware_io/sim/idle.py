"""Streams in which nobody touches the held object: what a dormant class has to learn to ignore.

Grasp baseline, noise, creep, force-control drift, arm motion, regrasps, closing and releasing: each
effect is one function that changes a ``Motion``, rendered by the protocol's contact and sensor chain.
Magnitudes are assumed physical values (docs/DORMANT.md), none chosen by a detector's result. Every
frame carries its *source*, so false events can be attributed. numpy only, deterministic for a seed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from firmware_io.recordings import arm_marks
from firmware_io.recordings.idle_stretches import SOURCES as IDLE_SOURCES
from firmware_io.recordings.recording import Recording
from firmware_io.sim import constants as K
from firmware_io.sim.actions import Motion, baseline, smooth
from firmware_io.sim.contact import blur_width, pad_pressure
from firmware_io.sim.hand import CREEP_GAIN, CREEP_TAU_S, SCAN_PERIOD_S, shear_tilt
from firmware_io.sim.lab import Lab, get_lab
from firmware_io.sim.paper_protocol import hand_sensor
from firmware_io.sim.scenario import (
    FINGER_ANGLES,
    OBJECT_MODELS,
    POSE_MODELS,
    POSES,
    TrialSetup,
    half_widths,
    make_subject,
    make_trial,
    pose_load,
)
from firmware_io.sim.sensor import HandSensor, average_scans, firmware_output, response
from firmware_io.sim.session import ScriptedEvent, simulate_session
from firmware_io.sim.streams import stream
from firmware_io.sim.timing import frame_stamps

SOURCES = IDLE_SOURCES
"""What a frame of an idle stream shows (index = code in ``meta["source_codes"]``), the names a
recorded session's idle stretches carry too: open hand; grasp held, nothing happening but noise,
creep and drift; the hand closing on an object; the hand opening; the arm moving (inertial load,
vibration, pose change, settling); the hand re-seating its grasp."""

HOLD_S = (20.0, 90.0)
"""assumed: the robot holds one object this long before it puts it down."""
OPEN_GAP_S = (1.0, 4.0)
"""assumed: the hand is open this long between objects."""
GRASP_RAMP_S = 0.3
"""the hand closes / opens over this time (as in the scripted session)."""

ARM_MOVE_EVERY_S = 15.0
ARM_MOVE_S = (0.8, 3.0)
ARM_PEAK_ACCEL = (0.5, 3.0)
"""assumed: a service arm's point-to-point move (minimum-jerk), about one every 15 s, peak
tool accelerations 0.5-3 m/s^2 (a UR5-class arm's default tool moves are ~1.2 m/s^2)."""
ARM_VIBRATION_ACCEL = (0.2, 1.0)
ARM_VIBRATION_HZ = (15.0, 40.0)
"""assumed: joint-motor / gearbox vibration at the tool while moving."""
SETTLE_HZ = (7.0, 13.0)
SETTLE_ZETA = (0.15, 0.3)
SETTLE_SHARE = 0.3
"""assumed: the arm's stop excites the object on the compliant fingers (the band of the
simulator's bump ringing), amplitude a share of the move's peak acceleration."""
POSE_CHANGE_PROB = 0.3
"""a move reorients the hand to another pose this often: the gravity load moves between fingers."""

REGRASP_EVERY_S = 60.0
REGRASP_DEPTH = (0.3, 0.7)
REGRASP_DIP_S = (0.15, 0.3)
REGRASP_RECOVER_S = (0.3, 0.6)
REGRASP_SHIFT_MM = 1.0
"""assumed: about once a minute the hand controller re-seats the grasp: force dips to 30-70 %,
recovers within about half a second, the contact moves by ~1 mm and the rubber's creep starts over."""

DRIFT_REL = 0.04
DRIFT_PERIOD_S = (20.0, 200.0)
"""assumed: the hand's force control drifts slowly, a few per cent over tens of seconds."""
BALL_ROLL_LIMIT_MM = 4.0
"""a held ball wanders (the baseline's random walk) but stays in the fingertips."""

INERTIAL_SHARE = 0.5
WEDGE_SHARE = 0.2
"""same split of a load as the simulator's gravity model (``scenario.pose_load``): half of an
in-plane load presses the fingers on that side, an outward load wedges 20 % into normal force."""


@dataclass(frozen=True)
class ArmMove:
    start_s: float
    duration_s: float
    peak_accel: float
    angle: float  # in-plane direction of the inertial load (rad)
    outward: float  # share of the load pulling out of the hand (-1..1)
    vib_accel: float
    vib_hz: float
    settle_hz: float
    settle_zeta: float
    new_pose: str | None


@dataclass(frozen=True)
class Regrasp:
    start_s: float
    depth: float
    dip_s: float
    recover_s: float
    shift_mm: np.ndarray  # [3]


@dataclass(frozen=True)
class HoldPlan:
    """One object held from ``close_s`` to ``release_s`` (seconds within the segment)."""

    setup: TrialSetup
    n_frames: int
    close_s: float
    release_s: float
    moves: tuple[ArmMove, ...]
    regrasps: tuple[Regrasp, ...]
    drift: np.ndarray  # [3, 3, 2]: finger, component, (period, phase); amplitude in drift_amp
    drift_amp: np.ndarray  # [3, 3]


def _poisson_times(rng: np.random.Generator, every_s: float, lo: float, hi: float) -> list[float]:
    times, t = [], lo
    while True:
        t += float(rng.exponential(every_s))
        if t >= hi:
            return times
        times.append(t)


def plan_hold(rng: np.random.Generator, duration_s: float, obj: str | None = None, pose: str | None = None,
              lab: Lab | None = None) -> HoldPlan:
    """Draw one hold: object (one of ``lab``'s), pose, placement, and when the arm moves and the hand regrasps."""
    lab = get_lab(lab)
    obj = obj or str(rng.choice(lab.objects))
    pose = pose or str(rng.choice(POSES))
    n_frames = max(1, math.ceil(duration_s / K.FRAME_PERIOD_S))
    nobody = make_subject("idle", rng)  # only the trial machinery needs one; it never acts
    setup = make_trial(nobody, OBJECT_MODELS[obj], POSE_MODELS[pose], "hold", duration_s, rng, onset_s=duration_s + 1.0,
                       grip=lab.grip)
    close_s, release_s = 0.3, duration_s - 0.5
    moves = []
    t = close_s + 1.0
    for start in _poisson_times(rng, ARM_MOVE_EVERY_S, close_s + 1.0, release_s - 4.0):
        if start < t:
            continue  # one move at a time
        dur = float(rng.uniform(*ARM_MOVE_S))
        if start + dur + 1.0 > release_s:
            break
        new_pose = str(rng.choice([p for p in POSES if p != pose])) if rng.random() < POSE_CHANGE_PROB else None
        moves.append(ArmMove(start, dur, float(rng.uniform(*ARM_PEAK_ACCEL)), float(rng.uniform(-np.pi, np.pi)),
                             float(rng.uniform(-1.0, 1.0)), float(rng.uniform(*ARM_VIBRATION_ACCEL)),
                             float(rng.uniform(*ARM_VIBRATION_HZ)), float(rng.uniform(*SETTLE_HZ)),
                             float(rng.uniform(*SETTLE_ZETA)), new_pose))
        pose = new_pose or pose
        t = start + dur + 1.0
    busy = [(m.start_s - 0.5, m.start_s + m.duration_s + 1.0) for m in moves]
    regrasps = []
    for start in _poisson_times(rng, REGRASP_EVERY_S, close_s + 2.0, release_s - 2.0):
        if any(a <= start <= b for a, b in busy):
            continue
        regrasps.append(Regrasp(start, float(rng.uniform(*REGRASP_DEPTH)), float(rng.uniform(*REGRASP_DIP_S)),
                                float(rng.uniform(*REGRASP_RECOVER_S)), rng.normal(0.0, REGRASP_SHIFT_MM, 3)))
    periods = rng.uniform(*DRIFT_PERIOD_S, (3, 3))
    phases = rng.uniform(0, 2 * np.pi, (3, 3))
    amp = DRIFT_REL / np.sqrt(3) * rng.uniform(0.5, 1.5, (3, 3))
    return HoldPlan(setup, n_frames, close_s, release_s, tuple(moves), tuple(regrasps),
                    np.stack([periods, phases], axis=-1), amp)


def plan_stretch(rng: np.random.Generator, source: str, duration_s: float, obj: str | None = None,
                 pose: str | None = None, lab: Lab | None = None) -> HoldPlan:
    """One recorded idle stretch of ``source`` (the recorder's prompt acted out by the simulated hand).

    ``quiet``: held from before the stretch to after it; ``arm_move``: point-to-point moves one
    after another (each as ``plan_hold`` draws them, 0.3-1 s apart); ``regrasp``: a re-seat every
    3-5 s; ``grasp``: the hand closes on the object 1 s in; ``release``: it opens 1 s in. Drift and
    creep as in a hold; the draws are this function's own, so ``plan_hold``'s streams are unchanged.
    """
    base = plan_hold(rng, duration_s, obj, pose, lab)
    held_from, held_to = -60.0, duration_s + 60.0  # the grasp closed well before, opened well after
    moves: list[ArmMove] = []
    regrasps: list[Regrasp] = []
    pose_now = base.setup.pose.name
    if source == "arm_move":
        t = float(rng.uniform(0.2, 0.8))
        while t + ARM_MOVE_S[0] < duration_s:
            dur = float(rng.uniform(*ARM_MOVE_S))
            new_pose = (str(rng.choice([p for p in POSES if p != pose_now])) if rng.random() < POSE_CHANGE_PROB
                        else None)
            moves.append(ArmMove(t, dur, float(rng.uniform(*ARM_PEAK_ACCEL)), float(rng.uniform(-np.pi, np.pi)),
                                 float(rng.uniform(-1.0, 1.0)), float(rng.uniform(*ARM_VIBRATION_ACCEL)),
                                 float(rng.uniform(*ARM_VIBRATION_HZ)), float(rng.uniform(*SETTLE_HZ)),
                                 float(rng.uniform(*SETTLE_ZETA)), new_pose))
            pose_now = new_pose or pose_now
            t += dur + float(rng.uniform(0.3, 1.0))
    elif source == "regrasp":
        t = float(rng.uniform(0.5, 1.5))
        while t + 1.0 < duration_s:
            regrasps.append(Regrasp(t, float(rng.uniform(*REGRASP_DEPTH)), float(rng.uniform(*REGRASP_DIP_S)),
                                    float(rng.uniform(*REGRASP_RECOVER_S)), rng.normal(0.0, REGRASP_SHIFT_MM, 3)))
            t += float(rng.uniform(3.0, 5.0))
    elif source == "grasp":
        held_from = 1.0
    elif source == "release":
        held_to = 1.0
    elif source not in ("quiet", "open"):
        raise ValueError(f"idle source {source!r}: one of {', '.join(SOURCES)}")
    return HoldPlan(base.setup, base.n_frames, held_from, held_to, tuple(moves), tuple(regrasps), base.drift,
                    base.drift_amp)


# -- effects on the contact state ----------------------------------------------------------------
def min_jerk(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position (0 -> 1) and acceleration (peak 1) of a minimum-jerk move over tau in [0, 1]."""
    x = np.clip(tau, 0.0, 1.0)
    pos = x**3 * (10 - 15 * x + 6 * x * x)
    acc = np.where((tau > 0) & (tau < 1), 60 * x - 180 * x * x + 120 * x**3, 0.0) / 5.7735
    return pos, acc


def inertial_load(mass_kg: float, accel: np.ndarray, angle: float, outward: float) -> tuple[np.ndarray, np.ndarray]:
    """Extra normal force per finger ``[3, S]`` and distal shear ``[S]`` of an acceleration (m/s^2).

    The object's inertia acts like extra gravity along the load direction: the in-plane part
    presses the fingers on that side (cosine share), the outward part wedges it into the tips
    and is carried by friction toward the tip (same split as ``scenario.pose_load``).
    """
    f = mass_kg * accel
    in_plane = math.sqrt(max(0.0, 1.0 - outward * outward))
    d_n = INERTIAL_SHARE * in_plane * np.cos(angle - FINGER_ANGLES)[:, None] * f[None, :]
    d_n = d_n + WEDGE_SHARE * outward * f[None, :]
    return d_n, -outward * f / 3.0


def arm_move(m: Motion, setup: TrialSetup, t: np.ndarray, move: ArmMove, pose: str) -> str:
    """The arm carries the hand from one place to another; returns the pose after the move."""
    tau = (t - move.start_s) / move.duration_s
    pos, acc = min_jerk(tau)
    inside = (tau > 0) & (tau < 1)
    vib = np.where(inside, move.vib_accel * np.sin(np.pi * np.clip(tau, 0, 1))
                   * np.sin(2 * np.pi * move.vib_hz * (t - move.start_s)), 0.0)
    after = np.clip(t - move.start_s - move.duration_s, 0.0, None)
    w = 2 * np.pi * move.settle_hz
    settle = np.where(t > move.start_s + move.duration_s,
                      SETTLE_SHARE * move.peak_accel * np.exp(-move.settle_zeta * w * after) * np.sin(w * after), 0.0)
    d_n, shear = inertial_load(setup.obj.mass_kg, move.peak_accel * acc + vib + settle, move.angle, move.outward)
    m.nd += d_n
    m.shear += shear
    if move.new_pose is None:
        return pose
    old_n, old_shift = pose_load(POSE_MODELS[pose], setup.obj)
    new_n, new_shift = pose_load(POSE_MODELS[move.new_pose], setup.obj)
    weight = setup.obj.mass_kg * K.GRAVITY
    m.nd += (new_n - old_n)[:, None] * pos[None, :]
    m.yd += (new_shift - old_shift) * pos[None, :]
    m.shear -= weight * (POSE_MODELS[move.new_pose].outward - POSE_MODELS[pose].outward) / 3.0 * pos[None, :]
    return move.new_pose


def regrasp(m: Motion, t: np.ndarray, r: Regrasp) -> None:
    """The hand loosens and re-closes; the object re-seats a little."""
    s = t - r.start_s
    down = smooth(s / r.dip_s)
    up = smooth((s - r.dip_s) / r.recover_s)
    m.nd *= (1.0 - r.depth * down * (1.0 - up))[None, :]
    m.yd += r.shift_mm[:, None] * down[None, :]


def drift(m: Motion, t: np.ndarray, plan: HoldPlan) -> None:
    """Slow force-control drift per finger: a sum of three slow sinusoids."""
    period, phase = plan.drift[..., 0], plan.drift[..., 1]
    wave = np.sin(2 * np.pi * t[None, None, :] / period[..., None] + phase[..., None])
    m.nd *= 1.0 + (plan.drift_amp[..., None] * wave).sum(axis=1)


def creep_gain(t: np.ndarray, plan: HoldPlan) -> np.ndarray:
    """Reading gain from the rubber's creep; it starts over at each close and regrasp."""
    loaded_since = np.full_like(t, plan.close_s)
    for r in plan.regrasps:
        loaded_since = np.where(t >= r.start_s + r.dip_s, r.start_s + r.dip_s, loaded_since)
    age = np.clip(t - loaded_since, 0.0, None)
    return 1.0 + CREEP_GAIN * (1.0 - np.exp(-age / CREEP_TAU_S))


def hold_motion(plan: HoldPlan, t: np.ndarray, rng: np.random.Generator) -> tuple[Motion, np.ndarray]:
    """Contact state at scan times ``t`` and the distal creep gain."""
    setup = plan.setup
    m = baseline(setup, t, rng)
    m.yd = setup.y0[:, None] + BALL_ROLL_LIMIT_MM * np.tanh((m.yd - setup.y0[:, None]) / BALL_ROLL_LIMIT_MM)
    m.xd = setup.x0[:, None] + BALL_ROLL_LIMIT_MM * np.tanh((m.xd - setup.x0[:, None]) / BALL_ROLL_LIMIT_MM)
    drift(m, t, plan)
    pose = setup.pose.name
    for move in plan.moves:
        pose = arm_move(m, setup, t, move, pose)
    for r in plan.regrasps:
        regrasp(m, t, r)
    env = smooth((t - plan.close_s) / GRASP_RAMP_S) * (1.0 - smooth((t - plan.release_s) / GRASP_RAMP_S))
    m.nd *= env[None, :]
    np.clip(m.nd, 0.0, None, out=m.nd)
    return m, creep_gain(t, plan)


def source_codes(plan: HoldPlan, n_frames: int) -> np.ndarray:
    """Per frame the index into SOURCES of what is going on (later effects take precedence)."""
    tf = (np.arange(n_frames) + 1.0) * K.FRAME_PERIOD_S  # end of each frame
    code = np.full(n_frames, SOURCES.index("quiet"), dtype=np.int8)

    def mark(a: float, b: float, name: str) -> None:
        code[(tf >= a) & (tf < b)] = SOURCES.index(name)

    for mv in plan.moves:
        mark(mv.start_s, mv.start_s + mv.duration_s + 0.5, "arm_move")
    for r in plan.regrasps:
        mark(r.start_s, r.start_s + r.dip_s + r.recover_s + 0.2, "regrasp")
    mark(-1.0, plan.close_s, "open")
    mark(plan.close_s, plan.close_s + GRASP_RAMP_S + 0.3, "grasp")
    mark(plan.release_s, plan.release_s + GRASP_RAMP_S + 0.2, "release")
    mark(plan.release_s + GRASP_RAMP_S + 0.2, 1e9, "open")
    return code


def move_marks(plan: HoldPlan, offset: int = 0) -> dict[int, bool]:
    """What a robot that tells the truth says about its arm during ``plan`` (frame -> moving): ``arm moving``
    from the frame in which a move starts, ``arm still`` from the frame in which it ends (its own
    plan, not the pads: the settling after the stop is the daemon's settle time). ``offset``: the
    hold's first frame in the stream."""
    out: dict[int, bool] = {}
    for mv in plan.moves:
        start = offset + max(0, math.ceil(mv.start_s / K.FRAME_PERIOD_S - 1.0 - 1e-9))
        stop = offset + max(0, math.ceil((mv.start_s + mv.duration_s) / K.FRAME_PERIOD_S - 1.0 - 1e-9))
        if stop < offset + plan.n_frames:
            out[stop] = False
        if start < offset + plan.n_frames:
            out[start] = True
    return out


def render_hold(plan: HoldPlan, sensor: HandSensor, rng: np.random.Generator) -> np.ndarray:
    """uint16 frames ``[n_frames, C]`` of one hold (open hand before the close and after the release)."""
    layout = sensor.layout
    setup = plan.setup
    n_scans = plan.n_frames * K.SCANS_PER_FRAME
    t = (np.arange(n_scans) + 0.5) * SCAN_PERIOD_S
    m, gain = hold_motion(plan, t, rng)
    signal = np.empty((plan.n_frames, layout.n_taxels), dtype=np.float32)
    sigma = np.full(n_scans, float(blur_width(setup.obj.soft_mm, setup.taped)))
    for pad in range(layout.n_matrices):
        finger, distal = pad // 2, pad % 2 == 1
        force = m.nd[finger] * gain if distal else m.np_[finger]
        wx, wy = half_widths(setup.obj, force)
        mat = layout.matrices[pad]
        kpa = pad_pressure(
            mat.cells_x, mat.cells_y, force=force,
            cx=m.xd[finger] if distal else np.full(n_scans, setup.x0[finger]),
            cy=m.yd[finger] if distal else m.yp[finger], wx=wx, wy=wy, sigma=sigma,
            tilt=shear_tilt(setup.tilt[finger], m.shear[finger], m.nd[finger]) if distal else np.zeros(n_scans),
        ).reshape(n_scans, -1)
        cols = layout.matrix_slice(pad)
        signal[:, cols] = average_scans(response(kpa, sensor.gain[cols], sensor.ceiling[cols]))
    return firmware_output(signal, sensor, rng)


# -- streams -------------------------------------------------------------------------------------
def idle_rng(seed: int, *key: object) -> np.random.Generator:
    """Substreams of idle data, disjoint from the protocol's and the session's."""
    return stream(seed, "event", "idle", *key)


def _open_frames(n: int, n_taxels: int) -> np.ndarray:
    return np.zeros((n, n_taxels), dtype=np.uint16)


def simulate_idle(duration_s: float, seed: int = 0, part: int = 0) -> Recording:
    """About ``duration_s`` of a hand that holds objects nobody touches (synthetic).

    Holds of 20-90 s with open-hand gaps between them. ``meta["source"]`` codes every frame
    (``SOURCES``); ``part`` gives independent streams under one seed (long evaluations are
    generated and replayed part by part to bound memory).
    """
    if duration_s <= 0:
        raise ValueError(f"duration must be positive, got {duration_s}")
    sensor = hand_sensor(seed)
    n_taxels = sensor.layout.n_taxels
    frames, codes, elapsed, i = [], [], 0.0, 0
    marks: dict[int, bool] = {}
    first = 0
    while elapsed < duration_s:
        rng = idle_rng(seed, part, i)
        gap = float(rng.uniform(*OPEN_GAP_S))
        n_gap = math.ceil(gap / K.FRAME_PERIOD_S)
        frames.append(_open_frames(n_gap, n_taxels))
        codes.append(np.zeros(n_gap, dtype=np.int8))
        hold_s = min(float(rng.uniform(*HOLD_S)), max(duration_s - elapsed - gap, 3.0))
        plan = plan_hold(rng, hold_s)
        frames.append(render_hold(plan, sensor, rng))
        codes.append(source_codes(plan, plan.n_frames))
        marks.update(move_marks(plan, first + n_gap))
        first += n_gap + plan.n_frames
        elapsed += (n_gap + plan.n_frames) * K.FRAME_PERIOD_S
        i += 1
    all_frames = np.concatenate(frames)
    code = np.concatenate(codes)
    stamps = frame_stamps(len(all_frames), idle_rng(seed, part, "timing"))
    meta = {"source": "synthetic idle stream (firmware_io.sim.idle)", "synthetic": True, "seed": int(seed),
            "part": int(part), "sources": list(SOURCES), "source_codes": code.tolist(),
            "frame_period_s": K.FRAME_PERIOD_S, arm_marks.KEY: arm_marks.encode(marks)}
    return Recording(sensor.layout, all_frames, stamps, [], meta)


def simulate_mixed(events: Sequence[ScriptedEvent], seed: int = 0, margin_s: float = 1.0,
                   min_hold_s: float = 6.0) -> Recording:
    """A scripted session whose open-hand gaps are filled with idle holds (synthetic).

    The events are rendered by ``simulate_session`` (object placed ~1 s before the person
    acts, taken away 1.8 s after); every gap long enough gets a hold in which nobody touches
    the object, ``margin_s`` of open hand on either side. ``meta["source_codes"]`` codes the
    idle frames (SOURCES) and marks the events' frames -1.
    """
    rec = simulate_session(events, seed=seed)
    sensor = hand_sensor(seed)
    frames = rec.frames.copy()
    code = np.zeros(rec.n_frames, dtype=np.int8)
    for tr in rec.trials:
        code[tr.first:tr.last + 1] = -1
    bounds = [-1] + [b for tr in rec.trials for b in (tr.first, tr.last)] + [rec.n_frames]
    margin = math.ceil(margin_s / K.FRAME_PERIOD_S)
    marks: dict[int, bool] = {}
    for k in range(0, len(bounds), 2):
        start, stop = bounds[k] + 1 + margin, bounds[k + 1] - margin  # [start, stop)
        if (stop - start) * K.FRAME_PERIOD_S < min_hold_s:
            continue
        rng = idle_rng(seed, "mixed", k // 2)
        plan = plan_hold(rng, (stop - start) * K.FRAME_PERIOD_S - 0.01)
        n = min(plan.n_frames, stop - start)
        frames[start:start + n] = render_hold(plan, sensor, rng)[:n]
        code[start:start + n] = source_codes(plan, plan.n_frames)[:n]
        hold_marks = {f: m for f, m in move_marks(plan, start).items() if f < start + n}
        if hold_marks and hold_marks[max(hold_marks)] and start + n < rec.n_frames:
            hold_marks[start + n] = False  # a move cut short by the hold's end: the arm stops with it
        marks.update(hold_marks)
    meta = {**rec.meta, "source": "synthetic mixed stream (firmware_io.sim.idle)", "sources": list(SOURCES),
            "source_codes": code.tolist(), arm_marks.KEY: arm_marks.encode(marks)}
    return Recording(rec.layout, frames, rec.timestamps, list(rec.trials), meta)


__all__ = ["SOURCES", "plan_hold", "plan_stretch", "render_hold", "simulate_idle", "simulate_mixed"]
