"""A daemon's capture folder: what the working day adds to a lab's data, and the one owner of its layout.

The daemon (``[capture] folder``) keeps every decided window as one recording and a sample of idle
stretches as others, in the recording format ``handover train`` reads; the robot's outcomes and a
person's labels sit beside them as small text files, so nothing rewrites a recording once written:

- ``event-<frame_last>-<unix ms>.hrec``: one trial, frames from before the window to after the
  report; ``trial.label`` is the class the daemon served (a proposal, not a label);
  ``meta[META_KEY]`` holds the decision (see ``EVENT_FIELDS``);
- ``idle-<first frame>-<unix ms>.hrec``: one idle stretch (``meta["idle_stretches"]``), no trial;
- ``outcomes.jsonl``: one JSON object per line, ``{"event": <file stem>, "outcome": <word>,
  "source": "control" | "ros2", "time": <unix s>}``, appended by the daemon;
- ``labels.json``: ``{<file stem>: <class>}``, written (atomically) by ``handover review``; only
  these events are trials to ``handover train``.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

from firmware_io.recordings.recording import SUFFIX

__all__ = [
    "CAPTURED_NAME", "EVENT_FIELDS", "EVENT_PREFIX", "IDLE_PREFIX", "LABELS_FILE", "META_KEY", "OUTCOMES_FILE", "OUTCOME_WORDS",
    "event_name", "idle_name", "outcome_problem", "proposed_label",
]

META_KEY = "capture"
EVENT_PREFIX = "event-"
IDLE_PREFIX = "idle-"
OUTCOMES_FILE = "outcomes.jsonl"
LABELS_FILE = "labels.json"
CAPTURED_NAME = re.compile(rf"({re.escape(EVENT_PREFIX)}|{re.escape(IDLE_PREFIX)})[0-9]+-([0-9]+){re.escape(SUFFIX)}")
"""The name of a recording the daemon wrote (group 2: its unix ms); any other file is not the capture's."""
EVENT_FIELDS = ("kind", "class", "scores", "model_id", "instance", "frame_first", "frame_last", "report_frame",
                "device_time_ms", "time", "trigger", "arm_moving", "grasp_closed")
"""``meta[META_KEY]`` of an event recording; ``report_frame`` is the frame (in the recording) the
decision was made on, ``frame_first``/``frame_last`` the event line's (device numbering)."""

OUTCOME_WORDS = ("taken", "kept", "dropped")
"""What the robot saw after an event: the person took the object, the hand still holds it, it fell.
A class name (``outcome pull``) is a person's label and is taken as it is."""


def event_name(frame_last: int, time_s: float) -> str:
    """The file stem of a captured event (sorted names are time order within one daemon run)."""
    return f"{EVENT_PREFIX}{int(frame_last):09d}-{int(time_s * 1000):013d}"


def idle_name(first_frame: int, time_s: float) -> str:
    """The file stem of a captured idle stretch."""
    return f"{IDLE_PREFIX}{int(first_frame):09d}-{int(time_s * 1000):013d}"


def outcome_problem(word: str, classes: Sequence[str]) -> str | None:
    """Why ``word`` is not an outcome for a model with ``classes``, or None."""
    if word in OUTCOME_WORDS or word in classes:
        return None
    return (f"unknown outcome {word[:40]!r}: say one of {', '.join(OUTCOME_WORDS)} or a class name "
            f"({', '.join(classes)})")


def proposed_label(decision: str, outcome: str | None, classes: Sequence[str]) -> str | None:
    """The label an outcome proposes for review, or None when it cannot tell: a class name is that class;
    ``taken`` is a pull. ``kept`` says only that it was not a pull, so it proposes nothing: confirming the
    decision would turn the serving model's hold-read-as-bump into a label. ``dropped`` and an event
    without an outcome propose nothing a person has not confirmed."""
    if outcome in classes:
        return outcome
    if outcome == "taken":
        return "pull" if "pull" in classes else None
    return None
