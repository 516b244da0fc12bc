"""The paper's data protocol: subjects x runs x poses x objects x actions, 3 s trials."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path

from firmware_io.layout import SensorLayout
from firmware_io.recordings.recording import ACTIONS, Recording
from firmware_io.sim import constants as K
from firmware_io.sim.hand import Job, render
from firmware_io.sim.lab import Lab, get_lab
from firmware_io.sim.scenario import OBJECT_MODELS, POSE_MODELS, POSES, Subject, make_subject, make_trial
from firmware_io.sim.sensor import HandSensor
from firmware_io.sim.streams import stream
from firmware_io.sim.timing import frame_stamps

PAUSE_BETWEEN_TRIALS_S = (1.0, 2.5)
"""paper: after 3 s the subject stops, about a second later re-places the object."""

def check_names(kind: str, given: Sequence[str], allowed: Sequence[str]) -> None:
    bad = [g for g in given if g not in allowed]
    if bad:
        raise ValueError(f"unknown {kind} {bad[0]!r}; choose from {', '.join(allowed)}")

def subject_names(n_subjects: int) -> list[str]:
    return [f"s{i}" for i in range(1, n_subjects + 1)]

def hand_sensor(seed: int, layout: SensorLayout | None = None, lab: Lab | str | None = None) -> HandSensor:
    """The one physical hand all of a lab's subjects used (same taxel gains and offsets in every file)."""
    lab = get_lab(lab)
    return HandSensor.build(layout or SensorLayout.sdh2(), stream(seed, "hand", *lab.key), lab)


def lab_subject(name: str, seed: int, lab: Lab) -> Subject:
    """Person ``name`` of ``lab`` under ``seed`` (another lab's people are other people)."""
    return make_subject(name, stream(seed, "subject", name, *lab.key), lab.strength, lab.speed)

def frames_for(duration: float) -> int:
    return max(1, round(duration / K.FRAME_PERIOD_S))

def simulate_subject(name: str, seed: int, runs: int, poses: Sequence[str], objects: Sequence[str],
                     actions: Sequence[str], duration: float, sensor: HandSensor, lab: Lab) -> Recording:
    """One subject's file: trials in the paper's order (pose, object, action, run)."""
    subject = lab_subject(name, seed, lab)
    n = frames_for(duration)
    jobs, fields = [], []
    for pose in poses:
        for obj in objects:
            for action in actions:
                for run in range(1, runs + 1):
                    rng = stream(seed, "trial", name, pose, obj, action, run)
                    setup = make_trial(subject, OBJECT_MODELS[obj], POSE_MODELS[pose], action, duration, rng,
                                       grip=lab.grip)
                    jobs.append(Job(setup, n, rng))
                    fields.append({
                        "subject": name, "object": obj, "pose": pose, "action": action, "run": run,
                        "extra": {"onset": int(setup.onset_s // K.FRAME_PERIOD_S), "onset_s": round(setup.onset_s, 4),
                                  "synthetic": True, "taped": setup.taped},
                    })
    frames = render(jobs, sensor)
    segments, start = [], 0.0
    for f, fld in zip(frames, fields, strict=True):
        key = (fld["pose"], fld["object"], fld["action"], fld["run"])
        t_rng = stream(seed, "timing", name, *key)
        stamps = frame_stamps(len(f), t_rng, start)
        segments.append((f, stamps, fld))
        start = float(stamps[-1]) + float(t_rng.uniform(*PAUSE_BETWEEN_TRIALS_S))
    meta = {
        "source": "synthetic (firmware_io.sim)", "synthetic": True, "seed": int(seed), "subject": name,
        "subject_profile": {k: (round(v, 4) if isinstance(v, float) else v) for k, v in asdict(subject).items()},
        "frame_period_s": K.FRAME_PERIOD_S, "taped": True, **lab.meta,
    }
    return Recording.concatenate(sensor.layout, segments, meta)

def simulate_protocol(seed: int = 0, n_subjects: int = 5, runs: int = 5, poses: Sequence[str] = POSES,
                      objects: Sequence[str] | None = None, actions: Sequence[str] = ACTIONS,
                      duration: float = 3.0, lab: Lab | str | None = None) -> list[Recording]:
    """One synthetic recording per subject ("s1".."sN") of ``lab`` (default A: its objects by default);
    each trial one ``duration`` s segment."""
    lab = get_lab(lab)
    objects = lab.objects if objects is None else objects
    check_names("pose", poses, POSES)
    check_names("object", objects, lab.objects)
    check_names("action", actions, ACTIONS)
    if n_subjects < 1 or runs < 1:
        raise ValueError("n_subjects and runs must be at least 1")
    if duration < 1.5:
        raise ValueError(f"trial duration {duration} s is too short (at least 1.5 s)")
    sensor = hand_sensor(seed, lab=lab)
    return [simulate_subject(name, seed, runs, poses, objects, actions, duration, sensor, lab)
            for name in subject_names(n_subjects)]

def write_protocol(out_dir: str | os.PathLike, seed: int = 0, **kw) -> list[Path]:
    """Write ``subject_s1.hrec`` ... into ``out_dir``; returns the paths."""
    out = Path(out_dir)
    paths = []
    for rec in simulate_protocol(seed=seed, **kw):
        paths.append(rec.save(out / f"subject_{rec.meta['subject']}.hrec"))
    return paths

def trial_counts(recordings: Sequence[Recording]) -> dict[str, int]:
    """Trials per action over recordings (for the CLI summary and tests)."""
    counts: dict[str, int] = {}
    for rec in recordings:
        for tr in rec.trials:
            counts[tr.action] = counts.get(tr.action, 0) + 1
    return counts

__all__ = ["hand_sensor", "lab_subject", "simulate_protocol", "trial_counts", "write_protocol"]
