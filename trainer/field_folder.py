"""A daemon's capture folder as ``handover review`` and ``handover train`` read it.

The layout, the outcome words and the label an outcome proposes belong to
``firmware_io.recordings.field_capture``; this module reads the folder (events, outcomes, labels),
writes the labels a person confirms, and turns confirmed events into trials for training. Nothing
here rewrites a recording: a label lives only in ``labels.json``. numpy only (review runs without
the training extra).
"""

from __future__ import annotations

import os
import stat
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

from firmware_io.errors import HandoverError
from firmware_io.recordings.bounded_zip import first_line, loads
from firmware_io.recordings.field_capture import (
    CAPTURED_NAME,
    EVENT_PREFIX,
    IDLE_PREFIX,
    LABELS_FILE,
    META_KEY,
    OUTCOMES_FILE,
    proposed_label,
)
from firmware_io.recordings.recording import SUFFIX, Recording, RecordingError, name_problem
from runtime.config import KNOWN_EVENTS
from runtime.health import write_json_atomically
from trainer.dataset import DECIDED_START

__all__ = [
    "CLASSES", "CapturedEvent", "FieldFolderError", "field_recordings", "is_capture_folder", "read_events",
    "read_labels", "write_labels",
]

CLASSES = tuple(KNOWN_EVENTS)
"""The labels a person may give a captured event: the four actions and dormant (a false event)."""
MAX_TEXT_BYTES = 64 << 20
"""The most outcomes.jsonl or labels.json read (a day of outcomes is a few hundred kB)."""
LATEST_TIME_S = 1e11
"""A captured event's unix time beyond this (year 5138) is junk: shown as unknown (time.localtime overflows)."""


class FieldFolderError(HandoverError, ValueError):
    """A capture folder that cannot be read as one; the message names the file and what to do."""


@dataclass(frozen=True)
class CapturedEvent:
    """One captured event: its recording, the served decision and what the robot said after it."""

    stem: str
    recording: Recording
    decision: str
    time: float | None
    outcome: str | None

    @property
    def meta(self) -> dict:
        meta = self.recording.meta.get(META_KEY)
        return meta if isinstance(meta, dict) else {}

    @property
    def reported(self) -> bool:
        """False for a window the daemon decided but did not report (kind "unreported": dormant, or a class
        not in ``scene.events``): the robot says no outcome about it."""
        return self.meta.get("kind") != "unreported"

    @property
    def proposed(self) -> str | None:
        """The label the robot's outcome proposes (``field_capture.proposed_label``)."""
        return proposed_label(self.decision, self.outcome, CLASSES)

    @property
    def window_first(self) -> int:
        """The first frame (within the recording) of the window the daemon decided on (-1: unknown)."""
        first, last = self.meta.get("frame_first"), self.meta.get("frame_last")
        if self.report_frame < 0 or not isinstance(first, int) or not isinstance(last, int):
            return -1
        return max(-1, self.report_frame - (last - first))

    @property
    def report_frame(self) -> int:
        """The frame the decision was made on, within the recording (-1: unknown)."""
        frame = self.meta.get("report_frame")
        return int(frame) if isinstance(frame, int) and 0 <= frame < self.recording.n_frames else -1


def _files(folder: Path, prefix: str) -> list[Path]:
    """The daemon's recordings of one kind (``CAPTURED_NAME``): any other name is no capture's, and is
    never read nor printed (a name can hold a terminal's escape sequences); nor is
    what is not a regular file (a FIFO would hang the reader)."""
    return sorted(p for p in folder.iterdir() if p.name.startswith(prefix) and CAPTURED_NAME.fullmatch(p.name)
                  and p.is_file())


def is_capture_folder(folder: str | os.PathLike) -> bool:
    """Whether ``folder`` holds what a daemon's ``[capture] folder`` writes (event or idle files, outcomes)."""
    folder = Path(folder)
    return folder.is_dir() and (bool(_files(folder, EVENT_PREFIX) or _files(folder, IDLE_PREFIX))
                                or (folder / OUTCOMES_FILE).is_file())


def _read_text(path: Path) -> str | None:
    """The file's text, None when it is absent; a file over ``MAX_TEXT_BYTES`` is refused."""
    try:
        with open(os.open(path, os.O_RDONLY | os.O_NONBLOCK), "rb") as fh:  # a FIFO must not hang review
            if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
                raise FieldFolderError(f"{path}: not a regular file (a FIFO, a device?); move it away")
            data = fh.read(MAX_TEXT_BYTES + 1)
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise FieldFolderError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if len(data) > MAX_TEXT_BYTES:
        raise FieldFolderError(f"{path}: over {MAX_TEXT_BYTES >> 20} MiB, not a file the daemon writes; move it away")
    return data.decode("utf-8", errors="replace")


def read_outcomes(folder: str | os.PathLike, say: Callable[[str], None] = lambda _line: None) -> dict[str, str]:
    """``{event stem: outcome word}``, the last outcome said of each event; unreadable lines are skipped
    and counted in one line to ``say``."""
    path = Path(folder) / OUTCOMES_FILE
    text = _read_text(path) or ""
    outcomes, bad = {}, 0
    for line in text.splitlines():
        try:
            entry = loads(line)
            if name_problem("outcome", entry["outcome"]):  # printed by review: the daemon writes only such words
                raise ValueError(entry["outcome"])
            outcomes[str(entry["event"])] = entry["outcome"]
        except (ValueError, KeyError, TypeError):
            bad += line.strip() != ""
    if bad:
        say(f"{path}: {bad} unreadable line{'s' if bad != 1 else ''} skipped")
    return outcomes


def read_labels(folder: str | os.PathLike) -> dict[str, str]:
    """``{event stem: class}`` of ``labels.json`` ({} when absent); a file that is not one raises, so
    nothing overwrites it silently."""
    path = Path(folder) / LABELS_FILE
    text = _read_text(path)
    if text is None:
        return {}
    try:
        labels = loads(text)
    except ValueError as exc:
        labels = exc
    if (not isinstance(labels, dict) or not all(isinstance(k, str) for k in labels)
            or not all(v in CLASSES for v in labels.values())):
        why = first_line(labels) if isinstance(labels, Exception) else f"labels must be one of {', '.join(CLASSES)}"
        raise FieldFolderError(f"{path}: not an object {{event: class}} ({why}); fix it or move it away "
                               "(it is not overwritten)")
    return labels


def write_labels(folder: str | os.PathLike, labels: dict[str, str]) -> None:
    """``labels.json`` replaced atomically (a temp file renamed): an interrupted review loses nothing."""
    try:
        write_json_atomically(Path(folder) / LABELS_FILE, dict(sorted(labels.items())))
    except OSError as exc:
        raise FieldFolderError(f"{Path(folder) / LABELS_FILE}: cannot write ({exc.strerror or exc})") from None


def _event(path: Path, outcomes: dict[str, str]) -> CapturedEvent:
    rec = Recording.load(path)
    meta = rec.meta.get(META_KEY)
    if len(rec.trials) != 1 or not isinstance(meta, dict):
        raise RecordingError(f"{path}: not a captured event (one trial and meta[{META_KEY!r}] expected)")
    decision = meta.get("class")
    if name_problem("class", decision):  # printed by review: junk (an escape sequence) is the trial's action
        decision = rec.trials[0].action
    when = meta.get("time")
    when = float(when) if isinstance(when, int | float) and 0 <= when < LATEST_TIME_S else None
    return CapturedEvent(path.stem, rec, decision, when, outcomes.get(path.stem))


def read_events(folder: str | os.PathLike, say: Callable[[str], None]) -> list[CapturedEvent]:
    """Every readable captured event in time order; a corrupt file is named to ``say`` and skipped.
    A folder that is no capture folder raises."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FieldFolderError(f"{folder}: no such folder")
    if not is_capture_folder(folder):
        raise FieldFolderError(f"{folder}: not a capture folder (no {EVENT_PREFIX}*{SUFFIX}, {IDLE_PREFIX}*{SUFFIX} "
                               f"or {OUTCOMES_FILE}); give the daemon's [capture] folder")
    outcomes = read_outcomes(folder, say)
    events = []
    for path in _files(folder, EVENT_PREFIX):
        try:
            events.append(_event(path, outcomes))
        except RecordingError as exc:
            say(f"skipped: {exc}")
    return events


def field_subject(meta: dict) -> str:
    """The subject captured data trains as: ``field`` and the daemon's instance, kept apart from lab
    subjects by grouped cross-validation."""
    instance = meta.get("instance") if isinstance(meta, dict) else None
    return f"field-{instance}"[:64] if isinstance(instance, str) and instance.isprintable() and instance else "field"


def field_recordings(folder: str | os.PathLike, say: Callable[[str], None]) -> tuple[list[Recording], list[str]]:
    """Recordings ``handover train`` reads from a capture folder, with their file names: each event with
    a label in labels.json as one trial of that class, cut at the window the daemon decided on
    (``trainer.dataset.DECIDED_START``), each idle file as idle (dormant data). Events
    without a label are skipped with one line."""
    folder = Path(folder)
    labels = read_labels(folder)
    events = read_events(folder, say)
    recs, names, unlabelled = [], [], 0
    for ev in events:
        label = labels.get(ev.stem)
        if label is None:
            unlabelled += 1
            continue
        trial = ev.recording.trials[0]
        extra = {**trial.extra, DECIDED_START: ev.window_first - trial.first} if ev.window_first >= trial.first else {}
        trial = replace(trial, subject=field_subject(ev.meta), action=label, extra=extra or trial.extra)
        recs.append(replace(ev.recording, trials=[trial]))
        names.append(f"{ev.stem}{SUFFIX}")
    if missing := len(labels.keys() - {ev.stem for ev in events}):
        say(f"{folder / LABELS_FILE}: {missing} label{'s' if missing != 1 else ''} name no readable event here "
            "(removed by capture.max_mb, moved, or corrupt); not trained on")
    if unlabelled:
        say(f"{folder}: {unlabelled} of {len(events)} captured events have no confirmed label and are skipped "
            f"(run `handover review {folder}`)")
    for path in _files(folder, IDLE_PREFIX):
        try:
            rec = Recording.load(path)
        except RecordingError as exc:
            say(f"skipped: {exc}")
            continue
        rec.meta = {**rec.meta, "subject": field_subject(rec.meta.get(META_KEY) or rec.meta)}
        recs.append(rec)
        names.append(path.name)
    if not recs:
        raise FieldFolderError(f"{folder}: no confirmed event and no idle to train on; label the events with "
                               f"`handover review {folder}` first")
    return recs, names
