"""What matters on a deployed robot, measured on long streams: false events per hour of idle,
detection delay from the person's onset, events missed, wrong class.

Streams are replayed frame by frame through the daemon's own ``Detector.feed``, so what is measured is
what the service would do. Modes (``MODES``): ``threshold`` and ``baseline`` (the paper's trigger, plain or
over a tracked baseline), ``onset``, ``onset_robot`` (the robot says when its grasp settles and lets go),
``onset_dormant`` and ``continuous`` (the 5-class model), and ``*_arm`` variants in which the robot
also says when its arm moves (the recording's marks, ``firmware_io.recordings.arm_marks``).
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from firmware_io.recordings.recording import Recording

__all__ = [
    "ARM_MODES", "DEFAULT_SETTING", "EARLY_FRAMES", "MODES", "Decision", "Truth", "apply_rule", "frame_decisions",
    "latency_stats", "macro_f1", "merge_idle", "replay", "score", "session_outcomes", "source_hours",
    "source_names", "sum_counts", "truths_of"
]

MODES = ("threshold", "baseline", "onset", "onset_robot", "onset_dormant", "continuous", "onset_arm",
         "onset_dormant_arm", "continuous_arm")
ARM_MODES = ("onset_arm", "onset_dormant_arm", "continuous_arm")
"""Modes in which the robot says when its arm moves (the recording's arm marks are sent)."""
TRIGGER_TABLE = {"threshold": {"kind": "threshold"}, "baseline": {"kind": "threshold", "baseline": True},
                 "onset": {"kind": "onset"}, "onset_robot": {"kind": "onset"}, "onset_dormant": {"kind": "onset"},
                 "continuous": {}, "onset_arm": {"kind": "onset"}, "onset_dormant_arm": {"kind": "onset"},
                 "continuous_arm": {}}
"""The ``[trigger]`` config table of each mode (unset keys: the model's recorded settings, else the defaults)."""
DEFAULT_SETTING = "onset_dormant"
"""The stream setting ``handover demo`` runs by default: the one ``./dev bench streams`` chose
by its rule on validation streams (results/streams.md, "How the default was chosen")."""
ROBOT_SETTLE_S = 0.3
"""The simulated robot says ``grasp closed`` this long after its 0.3 s closing ramp has ended."""
EARLY_FRAMES = 2
"""A decision up to this many frames before the annotated onset still counts for the event
(the onset is the start of a smooth movement, the frame grid is coarse)."""


@dataclass(frozen=True)
class Decision:
    """An event the daemon reported: the frame that ended its window and the class."""

    frame: int
    cls: str
    latency_us: float = 0.0


@dataclass(frozen=True)
class Truth:
    """A person's action: onset frame, last frame it can be reported at, the action."""

    onset: int
    end: int
    action: str


def replay(rec: Recording, model, mode: str, rule: dict | None = None,
           robot: dict[int, bool] | None = None, arm: dict[int, bool] | None = None,
           scene: dict | None = None) -> list[Decision]:
    """Feed every frame of ``rec`` to a fresh detector in ``mode``; the events it reports.

    ``rule``: the ``[continuous]`` config table (confirm_frames, min_margin, rearm_frames) for
    continuous mode; None takes the config defaults. ``robot``: frame index -> grasp closed
    (True) / open (False), passed to ``Detector.set_grasp`` before that frame (``onset_robot``
    computes them with ``robot_messages`` when not given). ``arm``: frame index -> arm moving, passed
    to ``Detector.set_arm_moving`` before that frame (the ``*_arm`` modes take the recording's marks,
    ``firmware_io.recordings.arm_marks.marks_of``, when not given). ``scene``: more ``[scene]`` keys
    (e.g. ``early_events``).
    """
    from firmware_io.client import Frame
    from runtime.config import config_from_dict
    from runtime.detector import Detector
    from runtime.scene import scene_problem

    if mode not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    pads = ",".join(str(p) for p in model.meta.pads)
    events = [c for c in model.meta.classes if c != model.meta.dormant_class]
    cfg = config_from_dict({
        "scene": {"pads": pads, "events": events, "mode": "continuous" if mode.startswith("continuous") else "trigger",
                  **(scene or {})},
        "trigger": dict(TRIGGER_TABLE[mode]),
        "continuous": dict(rule or {}),
    })
    problem = scene_problem(model, cfg, rec.layout)
    if problem:
        raise ValueError(f"model {model.model_id} cannot serve mode {mode!r}: {problem}")
    detector = Detector.from_config(cfg)
    detector.swap(model, rec.layout)
    stamps_ms = np.rint(rec.timestamps * 1000.0).astype(np.int64)
    frames = rec.frames
    clock = time.perf_counter
    feed = detector.feed
    if robot is None and mode == "onset_robot":
        robot = robot_messages(rec)
    robot = robot or {}
    if arm is None and mode in ARM_MODES:
        from firmware_io.recordings.arm_marks import marks_of

        arm = marks_of(rec.meta, rec.n_frames)
    arm = arm or {}
    out: list[Decision] = []
    for i in range(rec.n_frames):
        if i in robot:
            detector.set_grasp(robot[i], source="replay")
        if i in arm:
            detector.set_arm_moving(arm[i], source="replay")
        decision = feed(Frame(i, int(stamps_ms[i]), clock(), frames[i]))
        if decision is not None and decision.cls is not None:
            out.append(Decision(decision.frame.number, decision.cls, decision.latency_us))
    return out


def robot_messages(rec: Recording) -> dict[int, bool]:
    """When a robot would say ``grasp closed`` / ``grasp open`` in a simulated stream (frame -> closed).

    Idle holds (``meta["source_codes"]``): closed at the first ``quiet`` frame after a ``grasp``
    (0.3 s after the closing ramp), open at the first ``release`` frame. Scripted events: closed
    ``ROBOT_SETTLE_S`` after the closing ramp that precedes the onset, open when the hand starts
    to open to give the object away (``RELEASE_AFTER_S`` after the onset).
    """
    from firmware_io.sim import constants as K
    from firmware_io.sim.session import RELEASE_AFTER_S

    out: dict[int, bool] = {}
    codes = rec.meta.get("source_codes")
    names = list(rec.meta.get("sources", ()))
    if codes is not None and "grasp" in names:
        code = np.asarray(codes, dtype=np.int64)
        grasp, quiet, release = (names.index(n) for n in ("grasp", "quiet", "release"))
        prev = np.concatenate([[-2], code[:-1]])
        for i in np.flatnonzero((code == quiet) & (prev == grasp)):
            out[int(i)] = True
        for i in np.flatnonzero((code == release) & (prev != release)):
            out[int(i)] = False
    settle = int(np.ceil((0.3 + ROBOT_SETTLE_S) / K.FRAME_PERIOD_S))
    level = rec.frames.max(axis=1)
    for tr in rec.trials:
        onset = int(tr.extra["onset"])
        loaded = np.flatnonzero(level[tr.first:onset] > 0)
        if len(loaded):
            out[min(tr.first + int(loaded[0]) + settle, onset - 1)] = True
        onset_s = float(tr.extra.get("onset_s", onset * K.FRAME_PERIOD_S))
        out[round((onset_s + RELEASE_AFTER_S) / K.FRAME_PERIOD_S)] = False
    return dict(sorted(out.items()))


def frame_decisions(rec: Recording, model, batch: int = 2048) -> tuple[np.ndarray, np.ndarray]:
    """Offline: the model's label and scores for the window ending at every frame (T - 1 onwards).

    Row ``i`` belongs to the window ending at frame ``i + T - 1``. Used to choose the report
    rule's parameters cheaply; the daemon's replay must agree with it (tested).
    """
    T = int(model.meta.T)
    cols = rec.layout.columns(list(model.meta.pads))
    n = rec.n_frames - T + 1
    labels = np.empty(max(n, 0), dtype=np.int64)
    scores = np.empty((max(n, 0), len(model.meta.classes)), dtype=np.float32)
    for a in range(0, max(n, 0), batch):
        b = min(n, a + batch)
        x = rec.frames[a:b + T - 1, cols].astype(np.float32)
        windows = np.lib.stride_tricks.sliding_window_view(x, T, axis=0).transpose(0, 2, 1)
        lab, sc = model.run(np.ascontiguousarray(windows))
        labels[a:b], scores[a:b] = lab, sc
    return labels, scores


def apply_rule(labels: np.ndarray, scores: np.ndarray, model_meta, rule: dict | None = None,
               first_frame: int | None = None) -> list[Decision]:
    """Offline: the continuous report rule (runtime.decision, the daemon's own) on per-frame decisions."""
    from runtime.config import config_from_dict
    from runtime.decision import ContinuousDecision

    cc = config_from_dict({"continuous": dict(rule or {})}).continuous
    classes = list(model_meta.classes)
    events = {i for i, c in enumerate(classes) if c != model_meta.dormant_class}
    dec = ContinuousDecision(len(classes), classes.index(model_meta.dormant_class), cc.confirm_frames,
                             cc.min_margin, cc.rearm_frames, cc.gap_frames, cc.vote)
    start = int(model_meta.T) - 1 if first_frame is None else first_frame
    out = []
    for i in range(len(labels)):
        k = dec.update(int(labels[i]), scores[i])
        if k >= 0 and k in events:
            out.append(Decision(start + i, classes[k]))
    return out


def truths_of(rec: Recording) -> list[Truth]:
    """The scripted events of a session-like recording (absolute ``extra["onset"]``)."""
    out = []
    for tr in rec.trials:
        onset = int(tr.extra["onset"])
        out.append(Truth(onset, tr.last, tr.action))
    return out


def source_names(rec: Recording, n: int) -> np.ndarray:
    """Per frame what is going on: an idle source, ``event`` inside a scripted event, or ``?``."""
    codes = rec.meta.get("source_codes")
    names = list(rec.meta.get("sources", ()))
    if codes is None:
        return np.full(n, "?", dtype=object)
    table = np.asarray([*names, "event"], dtype=object)
    return table[np.asarray(codes, dtype=np.int64)]  # -1 -> "event"


def score(decisions: Sequence[Decision], truths: Sequence[Truth], n_frames: int, period_s: float,
          sources: np.ndarray | None = None, early: int = EARLY_FRAMES) -> dict:
    """Match reported events to the truth.

    Each truth owns the frames ``[onset - early, end]``; its first decision there is the
    detection (delay = decision frame - onset, wrong class when it differs), later ones are
    duplicates. Decisions outside every owned span are false events; their rate is per hour of
    the frames no truth owns. ``sources`` (per frame) attributes false events.
    """
    owner = np.full(n_frames, -1, dtype=np.int64)
    for i, t in enumerate(truths):
        owner[max(0, t.onset - early):min(n_frames, t.end + 1)] = i
    first: dict[int, Decision] = {}
    duplicates = 0
    false: list[Decision] = []
    for d in decisions:
        i = int(owner[d.frame]) if 0 <= d.frame < n_frames else -1
        if i < 0:
            false.append(d)
        elif i in first:
            duplicates += 1
        else:
            first[i] = d
    idle_frames = int(np.sum(owner < 0))
    idle_h = idle_frames * period_s / 3600.0
    delays = np.array([(first[i].frame - truths[i].onset) * period_s for i in sorted(first)])
    wrong = sum(first[i].cls != truths[i].action for i in first)
    per_action: dict[str, dict] = {}
    for i, t in enumerate(truths):
        a = per_action.setdefault(t.action, {"n": 0, "detected": 0, "correct": 0})
        a["n"] += 1
        a["detected"] += i in first
        a["correct"] += i in first and first[i].cls == t.action
    by_source: dict[str, int] = {}
    if sources is not None:
        for d in false:
            name = str(sources[d.frame]) if 0 <= d.frame < n_frames else "?"
            name = "pre_onset" if name == "event" else name
            by_source[name] = by_source.get(name, 0) + 1
    n = len(truths)
    delay_frames = np.array([first[i].frame - truths[i].onset for i in sorted(first)], dtype=np.float64)
    return {
        "per_class": per_class_scores(decisions, truths, first),
        "delay_frames": _stats(delay_frames),
        "delay_frames_per_class": per_class_delay([first[i].frame - truths[i].onset for i in sorted(first)],
                                                  [truths[i].action for i in sorted(first)]),
        "misses": [{"onset": truths[i].onset, "action": truths[i].action} for i in range(n) if i not in first],
        "wrong": [{"onset": truths[i].onset, "action": truths[i].action, "reported": first[i].cls}
                  for i in sorted(first) if first[i].cls != truths[i].action],
        "n_events": n,
        "detected": len(first),
        "missed": n - len(first),
        "wrong_class": int(wrong),
        "correct": len(first) - int(wrong),
        "recall": len(first) / n if n else None,
        "correct_rate": (len(first) - wrong) / n if n else None,
        "duplicates": duplicates,
        "delay_s": _stats(delays),
        "per_action": per_action,
        "false_events": len(false),
        "idle_hours": idle_h,
        "false_per_hour": len(false) / idle_h if idle_h > 0 else None,
        "false_by_source": dict(sorted(by_source.items())),
        "false_by_class": _count(d.cls for d in false),
        "decisions": len(decisions),
    }


def per_class_scores(decisions: Sequence[Decision], truths: Sequence[Truth], first: dict[int, Decision]) -> dict:
    """Per class: precision (first reports of the right class / all reports of that class,
    duplicates and false events included), recall (of the scripted events), F1."""
    right = Counter(d.cls for i, d in first.items() if d.cls == truths[i].action)
    said, scripted = Counter(d.cls for d in decisions), Counter(t.action for t in truths)
    out = {}
    for c in sorted(said.keys() | scripted.keys()):  # counted once: classes x reports was hours for 50,000 names
        tp, reported, n = right[c], said[c], scripted[c]
        p = tp / reported if reported else None
        r = tp / n if n else None
        f1 = 2 * p * r / (p + r) if p and r else (0.0 if p is not None and r is not None else None)
        out[c] = {"n": n, "reported": reported, "correct": tp, "precision": p, "recall": r, "f1": f1}
    return out


def macro_f1(per_class: dict) -> float | None:
    """Mean F1 over the scripted classes (a class never reported and never scripted does not count)."""
    values = [v["f1"] if v["f1"] is not None else 0.0 for v in per_class.values() if v["n"]]
    return float(np.mean(values)) if values else None


def _count(items) -> dict[str, int]:
    out: dict[str, int] = {}
    for x in items:
        out[x] = out.get(x, 0) + 1
    return dict(sorted(out.items()))


def per_class_delay(delays: Sequence[int], actions: Sequence[str]) -> dict:
    """Onset-to-report frames per true action: median and p90 (and the rest of ``_stats``)."""
    d, a = np.asarray(delays, dtype=np.float64), np.asarray(actions)
    return {c: _stats(d[a == c]) for c in sorted(set(a.tolist()))}


def _stats(x: np.ndarray) -> dict | None:
    if len(x) == 0:
        return None
    p10, p50, p90 = np.percentile(x, [10, 50, 90])
    return {k: round(float(v), 3) for k, v in  # frames: a thousandth is plenty, and 10.1 reads as 10.1
            (("mean", x.mean()), ("p10", p10), ("median", p50), ("p90", p90), ("min", x.min()), ("max", x.max()))}


def sum_counts(counts: Iterable[dict]) -> dict:
    """Counts (or hours) summed key by key over several dicts; keys in the order first met."""
    out: dict = {}
    for d in counts:
        for k, v in d.items():
            out[k] = out.get(k, 0) + v
    return out


def merge_idle(scores: Sequence[dict]) -> dict:
    """False events and idle hours summed over several idle parts."""
    hours = sum(s["idle_hours"] for s in scores)
    false = sum(s["false_events"] for s in scores)
    by_source = sum_counts(s["false_by_source"] for s in scores)
    by_class = sum_counts(s["false_by_class"] for s in scores)
    return {"idle_hours": hours, "false_events": false, "false_per_hour": false / hours if hours else None,
            "false_by_source": dict(sorted(by_source.items())), "false_by_class": dict(sorted(by_class.items()))}


def source_hours(recs: Sequence[Recording], period_s: float) -> dict[str, float]:
    """Hours of each idle source over the streams (to read false events per source as rates)."""
    out: dict[str, float] = {}
    for rec in recs:
        names = source_names(rec, rec.n_frames)
        for name, n in zip(*np.unique(names.astype(str), return_counts=True), strict=True):
            out[str(name)] = out.get(str(name), 0.0) + float(n) * period_s / 3600.0
    return dict(sorted(out.items()))


def latency_stats(decisions: Sequence[Decision]) -> dict | None:
    """Median and p99 (us) from the last frame's arrival to the decision, over reported events."""
    lat = np.array([d.latency_us for d in decisions if d.latency_us > 0])
    if len(lat) == 0:
        return None
    p50, p99 = np.percentile(lat, [50, 99])
    return {"n": len(lat), "median_us": float(p50), "p99_us": float(p99)}


def session_outcomes(decisions: Sequence[Decision], trials: Sequence) -> dict:
    """The demo's matching of reported events to a scripted session.

    A report inside an event's trial span (the object placed .. taken away) belongs to that
    event: the first is its answer, later ones are repeats; a report outside every span is an
    event outside any scripted event. Per class: precision = right first answers / all reports
    of that class, recall = right first answers / scripted events of that class.
    """
    firsts = np.array([t.first for t in trials], dtype=np.int64)
    answer: dict[int, Decision] = {}
    repeats, outside = 0, []
    for d in decisions:
        k = int(np.searchsorted(firsts, d.frame, side="right")) - 1
        if k < 0 or d.frame > trials[k].last:
            outside.append({"frame": d.frame, "reported": d.cls})
        elif k in answer:
            repeats += 1
        else:
            answer[k] = d
    truths = [Truth(int(t.extra.get("onset", t.first)), t.last, t.action) for t in trials]
    per_class = per_class_scores(decisions, truths, answer)
    correct = sum(answer[k].cls == trials[k].action for k in answer)
    return {
        "expected": len(trials), "detected": len(answer), "correct": correct, "missed": len(trials) - len(answer),
        "outside": len(outside), "repeats": repeats,
        "correct_fraction": correct / len(trials) if len(trials) else None,
        "per_class": per_class,
        "missed_events": [{"event": k + 1, "action": trials[k].action, "onset": truths[k].onset}
                          for k in range(len(trials)) if k not in answer],
        "wrong_events": [{"event": k + 1, "action": trials[k].action, "reported": answer[k].cls,
                          "frame": answer[k].frame, "onset": truths[k].onset}
                         for k in sorted(answer) if answer[k].cls != trials[k].action],
        "outside_events": outside,
        "report_minus_onset_frames": _stats(np.array([answer[k].frame - truths[k].onset for k in sorted(answer)],
                                                     dtype=np.float64)),
        "report_minus_onset_frames_per_class": per_class_delay([answer[k].frame - truths[k].onset for k in sorted(answer)],
                                                               [truths[k].action for k in sorted(answer)]),
    }
