"""Capture folders as a daemon's ``[capture] folder`` writes them (firmware_io.recordings.field_capture's
names), made from simulated trials and idle (synthetic) for the tests of review and train."""

from __future__ import annotations

import json
from pathlib import Path

from firmware_io.recordings.field_capture import META_KEY, OUTCOMES_FILE, event_name, idle_name
from firmware_io.recordings.idle_stretches import idle_meta
from firmware_io.recordings.recording import Recording, Trial

T0 = 1_800_000_000.0


def event_recording(rec: Recording, trial: Trial, decision: str, frame_last: int, when: float,
                    kind: str = "event") -> Recording:
    """One captured event: the trial's frames, its trial relabelled as the daemon served it."""
    frames, stamps = rec.trial_frames(trial)
    meta = {"kind": kind, "class": decision, "scores": {}, "model_id": "m1", "instance": "robot1",
            "frame_first": frame_last - 14, "frame_last": frame_last, "report_frame": len(frames) // 2,
            "device_time_ms": int(when * 1000) % 2**32, "time": when, "trigger": "onset", "arm_moving": False,
            "grasp_closed": True}
    served = Trial("daemon", trial.object, trial.pose, decision, trial.run, 0, len(frames) - 1)
    return Recording(rec.layout, frames, stamps - stamps[0], [served], {META_KEY: meta})


def make_capture(folder: Path, rec: Recording, decisions: list[str], outcomes: list[str | None],
                 idle: Recording | None = None, unreported: tuple[int, ...] = ()) -> list[str]:
    """Events from ``rec``'s first trials (served as ``decisions``, then ``outcomes`` said of each; None:
    nothing said; ``unreported``: indices of windows decided but not reported) and one idle file of ``idle``'s
    frames; returns the event stems in time order."""
    folder.mkdir(parents=True, exist_ok=True)
    stems, lines = [], []
    for i, (decision, outcome) in enumerate(zip(decisions, outcomes, strict=True)):
        when = T0 + 60 * i
        stem = event_name(1000 * (i + 1), when)
        kind = "unreported" if i in unreported else "event"
        event_recording(rec, rec.trials[i], decision, 1000 * (i + 1), when, kind).save(folder / f"{stem}.hrec")
        stems.append(stem)
        if outcome is not None:
            lines.append(json.dumps({"event": stem, "outcome": outcome, "source": "control", "time": when + 2}))
    (folder / OUTCOMES_FILE).write_text("".join(f"{line}\n" for line in lines))
    if idle is not None:
        n = idle.n_frames
        meta = {**idle_meta(n, [{"index": 0, "source": "quiet", "first": 0, "last": n - 1}]),
                META_KEY: {"kind": "idle", "instance": "robot1"}}
        Recording(idle.layout, idle.frames, idle.timestamps, [], meta).save(folder / f"{idle_name(5, T0)}.hrec")
    return stems
