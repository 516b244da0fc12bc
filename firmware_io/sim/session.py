"""A free-running session: the hand idles, an object is placed, a person acts at a scripted
time, the object is taken away, and so on. Used by the emulator and the end-to-end demo."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from firmware_io.recordings.recording import ACTIONS, Recording, Trial
from firmware_io.sim import constants as K
from firmware_io.sim.hand import Job, render
from firmware_io.sim.lab import Lab, get_lab
from firmware_io.sim.paper_protocol import check_names, hand_sensor, lab_subject, subject_names
from firmware_io.sim.scenario import OBJECT_MODELS, OBJECTS, POSE_MODELS, POSES, make_trial
from firmware_io.sim.streams import stream
from firmware_io.sim.timing import frame_stamps

__all__ = ["DEMO_SESSION_SEED", "DEMO_TRAIN_SEED", "HELD_OUT_SEED_OFFSET", "RELEASE_AFTER_S", "ScriptedEvent",
           "demo_script", "simulate_session"]

DEMO_TRAIN_SEED = 0
"""Simulator seed the demo's models train on (``handover demo --seed``): its protocol, idle and session."""
HELD_OUT_SEED_OFFSET = 1000
"""A session played to a model trained on seed s uses seed s + this. The simulator draws its people
and hand from the seed, so under the same seed a session replays the trained subjects."""
DEMO_SESSION_SEED = DEMO_TRAIN_SEED + HELD_OUT_SEED_OFFSET
"""The demo's scripted session, also what ``handover emulate`` plays by default: no demo model saw it."""

GRASP_BEFORE_S = (0.9, 1.4)
"""the object is placed and grasped this long before the person acts."""
RELEASE_AFTER_S = 1.8
"""the object is taken away (hand opens) this long after the onset."""
MIN_SPACING_S = 2.5


@dataclass(frozen=True)
class ScriptedEvent:
    """The person does ``action`` at ``time`` seconds after the session starts."""

    time: float
    action: str
    subject: str
    object: str
    pose: str

    def to_dict(self) -> dict:
        return {"time": self.time, "action": self.action, "subject": self.subject,
                "object": self.object, "pose": self.pose}


def demo_script(n_events: int = 40, seed: int = 0, gap: tuple[float, float] = (3.0, 5.0),
                objects: Sequence[str] = OBJECTS) -> list[ScriptedEvent]:
    """A mix of the four actions (balanced, shuffled), subjects s1..s5, ``objects`` (a lab's) and poses."""
    if n_events < 0:
        raise ValueError("n_events must be >= 0")
    if gap[0] < MIN_SPACING_S or gap[1] < gap[0]:
        raise ValueError(f"gap must be (lo, hi) with {MIN_SPACING_S} <= lo <= hi, got {gap}")
    rng = stream(seed, "script")
    actions = np.resize(np.array(ACTIONS), n_events)
    rng.shuffle(actions)
    subjects = subject_names(5)
    events, t = [], 2.0
    for action in actions:
        t += float(rng.uniform(*gap))
        events.append(ScriptedEvent(round(t, 3), str(action), str(rng.choice(subjects)),
                                    str(rng.choice(objects)), str(rng.choice(POSES))))
    return events


def _check(events: Sequence[ScriptedEvent], lab: Lab) -> None:
    check_names("action", [e.action for e in events], ACTIONS)
    check_names("object", [e.object for e in events], lab.objects)
    check_names("pose", [e.pose for e in events], POSES)
    for a, b in itertools.pairwise(events):
        if b.time - a.time < MIN_SPACING_S:
            raise ValueError(f"events at {a.time} s and {b.time} s are closer than {MIN_SPACING_S} s "
                             "(the object must be taken away and placed again)")
    if events and events[0].time < 1.0:
        raise ValueError(f"first event at {events[0].time} s: it needs at least 1 s of grasp before it")


def simulate_session(events: Sequence[ScriptedEvent], seed: int = 0, lead_in: float = 2.0,
                     tail: float = 3.0, lab: Lab | str | None = None) -> Recording:
    """Continuous synthetic stream of ``lab``'s hand and people (default A); one Trial per event,
    ``extra["onset"]`` = absolute frame."""
    lab = get_lab(lab)
    events = sorted(events, key=lambda e: e.time)
    _check(events, lab)
    period = K.FRAME_PERIOD_S
    end_s = max([lead_in] + [e.time + RELEASE_AFTER_S + 0.5 for e in events]) + tail
    n_total = math.ceil(end_s / period)
    sensor = hand_sensor(seed, lab=lab)
    jobs, spans, fields = [], [], []
    prev_end = 0
    for i, ev in enumerate(events):
        rng = stream(seed, "event", i, round(ev.time * 1000), ev.action, ev.subject, ev.object, ev.pose)
        close_s = max(ev.time - float(rng.uniform(*GRASP_BEFORE_S)), prev_end * period, 0.0)
        first = max(int(close_s // period), prev_end)
        last = min(math.ceil((ev.time + RELEASE_AFTER_S + 0.4) / period), n_total - 1)
        seg_t0 = first * period
        subject = lab_subject(ev.subject, seed, lab)
        n = last - first + 1
        setup = make_trial(subject, OBJECT_MODELS[ev.object], POSE_MODELS[ev.pose], ev.action, n * period, rng,
                           onset_s=ev.time - seg_t0, grip=lab.grip)
        window = (close_s - seg_t0, ev.time + RELEASE_AFTER_S - seg_t0)
        jobs.append(Job(setup, n, rng, window))
        spans.append((first, last))
        fields.append({"subject": ev.subject, "object": ev.object, "pose": ev.pose, "action": ev.action,
                       "run": i + 1, "extra": {"onset": int(ev.time // period), "onset_s": ev.time,
                                               "synthetic": True, "taped": True}})
        prev_end = last + 1
    frames = np.zeros((n_total, sensor.layout.n_taxels), dtype=np.uint16)
    for (first, last), f in zip(spans, render(jobs, sensor), strict=True):
        frames[first:last + 1] = f
    stamps = frame_stamps(n_total, stream(seed, "timing", "session"))
    trials = [Trial(first=a, last=b, **fld) for (a, b), fld in zip(spans, fields, strict=True)]
    meta = {"source": "synthetic session (firmware_io.sim)", "synthetic": True, "seed": int(seed),
            "script": [e.to_dict() for e in events], "lead_in": lead_in, "tail": tail,
            "frame_period_s": period, **lab.meta}
    return Recording(sensor.layout, frames, stamps, trials, meta)
