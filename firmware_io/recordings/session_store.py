"""A subject's session file as the session state: one segment per trial or idle stretch, saved at every change.

The file is the only state, so a session stopped by Ctrl-C, a crash, an unplugged device or a full disk
resumes by reading it; a change the disk refuses is undone in memory, so the store always says what the
file holds.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from firmware_io.errors import HandoverError
from firmware_io.frame_timing import NOMINAL_PERIOD_S
from firmware_io.layout import SensorLayout
from firmware_io.recordings import arm_marks
from firmware_io.recordings.idle_stretches import IdleSlot, idle_meta, stretches_of
from firmware_io.recordings.recording import MAX_NAME_CHARS, Recording, remove_stale_temps

if TYPE_CHECKING:
    from firmware_io.recordings.record_session import ProtocolPlan, TrialSlot

__all__ = ["NotSaved", "SessionError", "SessionStore", "recording_path", "subject_problem"]

NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")
"""A pose, object, action or subject name (matched whole: ``$`` let a name end in a newline)."""


def subject_problem(subject: str) -> str | None:
    """Why ``subject`` cannot be a subject id (recorded or imported), None when it can."""
    if len(subject) > MAX_NAME_CHARS:
        return f"subject id {subject[:24]!r}... has {len(subject)} characters; use at most {MAX_NAME_CHARS}"
    if not NAME_PATTERN.fullmatch(subject):
        return f"subject id {subject!r}: use letters, digits, '_', '-' or '.'"
    return None


class SessionError(HandoverError, ValueError):
    """A session that cannot start or continue (bad plan, foreign file, other sensor)."""


def recording_path(out_dir: str | Path, subject: str) -> Path:
    return Path(out_dir) / f"subject_{subject}.hrec"


IDLE_KEY = "idle"
"""A segment's fields under this key make it an idle stretch (source, plan index, annotations), not a trial."""
DERIVED_META = ("idle_stretches", "sources", "source_codes", arm_marks.KEY)
"""Metadata written from the segments on every save, never carried over from the file read."""


@dataclass
class _Segment:
    frames: np.ndarray
    stamps: np.ndarray
    fields: dict


class NotSaved(SessionError):
    """A change the disk refused (full, gone): the store is undone to what the file holds."""


class SessionStore:
    """A subject's recording held as one segment per trial; every change is saved at once."""

    def __init__(self, path: Path, layout: SensorLayout, subject: str, meta: dict,
                 segments: list[_Segment] | None = None) -> None:
        self.path = Path(path)
        self.layout = layout
        self.subject = subject
        self.meta = meta
        self.segments: list[_Segment] = segments or []

    @classmethod
    def open(cls, path: str | Path, subject: str, layout: SensorLayout) -> SessionStore:
        """Continue the subject's file if it exists (checking subject and sensor), else start one."""
        path = Path(path)
        if problem := subject_problem(subject):
            raise SessionError(problem)
        remove_stale_temps(path)  # a save killed mid-write (kill -9, power loss) left its temp file
        if not path.exists():
            return cls(path, layout, subject, {"subject": subject, "sessions": []})
        rec = Recording.load(path)  # RecordingError names the file
        if str(rec.meta.get("subject", subject)) != subject:
            raise SessionError(f"{path}: belongs to subject {rec.meta.get('subject')!r}, not {subject!r}")
        if rec.layout.to_dict() != layout.to_dict():
            raise SessionError(
                f"{path}: recorded with another sensor layout ({rec.layout.n_taxels} taxels in "
                f"{rec.layout.n_matrices} pads; the device has {layout.n_taxels} in {layout.n_matrices})"
            )
        placed = []
        for t in rec.trials:
            fields = {k: v for k, v in t.to_dict().items() if k not in ("first", "last")}
            placed.append((t.first, t.last, fields))
        for st in stretches_of(rec.meta):
            placed.append((st["first"], st["last"], {IDLE_KEY: {k: v for k, v in st.items()
                                                                if k not in ("first", "last")}}))
        segments = [_Segment(rec.frames[a:b + 1].copy(), rec.timestamps[a:b + 1].copy(), fields)
                    for a, b, fields in sorted(placed, key=lambda p: p[0])]
        meta = {k: v for k, v in rec.meta.items() if k not in DERIVED_META}
        meta.setdefault("subject", subject)
        meta.setdefault("sessions", [])
        return cls(path, layout, subject, meta, segments)

    @property
    def n_trials(self) -> int:
        return sum(IDLE_KEY not in s.fields for s in self.segments)

    @property
    def n_idle(self) -> int:
        """Idle stretches recorded."""
        return sum(IDLE_KEY in s.fields for s in self.segments)

    def idle_seconds(self) -> float:
        """Seconds of idle recorded (frame count x median frame interval)."""
        frames = sum(len(s.frames) for s in self.segments if IDLE_KEY in s.fields)
        stamps = [s.stamps for s in self.segments if len(s.stamps) > 1]
        period = float(np.median(np.concatenate([np.diff(t) for t in stamps]))) if stamps else NOMINAL_PERIOD_S
        return frames * period

    def remaining_idle(self, plan: Sequence[IdleSlot]) -> list[IdleSlot]:
        done = {int(s.fields[IDLE_KEY]["index"]) for s in self.segments if IDLE_KEY in s.fields}
        return [s for s in plan if s.index not in done]

    def remaining(self, plan: ProtocolPlan) -> list[TrialSlot]:
        done = {(s.fields["pose"], s.fields["object"], s.fields["action"], int(s.fields["run"]))
                for s in self.segments if IDLE_KEY not in s.fields}
        return [s for s in plan.slots() if s.key not in done]

    def add(self, slot: TrialSlot, frames: np.ndarray, stamps: np.ndarray, extra: dict) -> int:
        """Append a trial and save; returns its index. Timestamps stay strictly increasing."""
        fields = {"subject": self.subject, "object": slot.object, "pose": slot.pose, "action": slot.action,
                  "run": slot.run, "extra": dict(extra)}
        self._append(frames, stamps, fields)
        return self.n_trials - 1

    def add_idle(self, slot: IdleSlot, frames: np.ndarray, stamps: np.ndarray, extra: dict) -> None:
        """Append an idle stretch and save."""
        self._append(frames, stamps, {IDLE_KEY: {"source": slot.source, "index": slot.index,
                                                 "seconds": slot.seconds, "extra": dict(extra)}})

    def _append(self, frames: np.ndarray, stamps: np.ndarray, fields: dict) -> None:
        """A segment after the last one, timestamps kept strictly increasing; saved at once."""
        stamps = np.asarray(stamps, dtype=np.float64)
        if self.segments:
            last = float(self.segments[-1].stamps[-1])
            if stamps[0] <= last:  # the PC clock went back (or a foreign file): keep the order
                stamps = stamps + (last - stamps[0] + 1e-3)
        self.segments.append(_Segment(np.asarray(frames, dtype=np.uint16), stamps, fields))
        self._save_or(self.segments.pop, "the recording just made could not be saved and is lost")

    def remove_last(self) -> None:
        """Drop the newest trial (redo or discard) and save."""
        if self.segments:
            last = self.segments.pop()
            self._save_or(lambda: self.segments.append(last), "the last trial could not be dropped and stays saved")

    def _save_or(self, undo: Callable[[], None], what: str) -> None:
        """Save; when the disk refuses (full, gone) undo the change, so the store is what the file holds, and
        raise NotSaved saying ``what``: the file keeps every earlier save, so running again resumes."""
        try:
            self.save()
        except OSError as exc:
            undo()
            raise NotSaved(f"{what} ({exc.strerror or exc})") from None

    def to_recording(self) -> Recording:
        rec = Recording.concatenate(self.layout, ((s.frames, s.stamps, None if IDLE_KEY in s.fields else s.fields)
                                                  for s in self.segments), self.meta)
        stretches, pos = [], 0
        for s in self.segments:
            if IDLE_KEY in s.fields and len(s.frames):
                stretches.append({"first": pos, "last": pos + len(s.frames) - 1, **s.fields[IDLE_KEY]})
            pos += len(s.frames)
        rec.meta.update(idle_meta(rec.n_frames, stretches))
        marks = self._arm_marks()
        if marks:
            rec.meta[arm_marks.KEY] = arm_marks.encode(marks)
        return rec

    def _arm_marks(self) -> dict[int, bool]:
        """The robot's arm marks of every segment (``extra["arm_marks"]``, segment frames) on the file's frames."""
        out: dict[int, bool] = {}
        pos = 0
        for s in self.segments:
            extra = s.fields.get(IDLE_KEY, s.fields).get("extra", {})
            for frame, moving in extra.get(arm_marks.KEY, ()):
                out[pos + int(frame)] = bool(moving)
            pos += len(s.frames)
        return out

    def save(self) -> Path:
        return self.to_recording().save(self.path)
