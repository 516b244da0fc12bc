"""The capture folder's one writer: a thread that saves what the hot path hands it, never the other way.

Why a thread of its own: a recording is written with fsync and renamed (``Recording.save``), which can take
milliseconds, and a full or read-only disk must cost the robot nothing. ``put`` never blocks: a full queue
drops the item and counts it. The writer keeps the folder below ``max_mb`` by removing the oldest
recordings first, logs ONE line when the folder stops taking files (full disk, read-only, gone) and one
when it takes them again, and keeps trying with every later item. The layout is
``firmware_io.recordings.field_capture``'s.
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import queue
import re
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from firmware_io.errors import HandoverError
from firmware_io.layout import SensorLayout
from firmware_io.recordings.field_capture import CAPTURED_NAME, EVENT_PREFIX, IDLE_PREFIX, LABELS_FILE, OUTCOMES_FILE
from firmware_io.recordings.idle_stretches import idle_meta
from firmware_io.recordings.recording import SUFFIX, Recording, Trial
from runtime.control_access import untrusted_folder
from runtime.health import one_line

__all__ = ["Capture", "CaptureError", "CaptureWriter", "Outcome", "folder_problem", "folder_unwritable"]

log = logging.getLogger("handover.capture")

QUEUE_ITEMS = 16
"""Captures waiting for the writer at most (an event is ~80 kB, an idle stretch ~300 kB): a writer stuck
on a slow disk holds at most a few MB; the rest is dropped and counted."""
DROP_LOG_EVERY = 100
"""One log line for the first item dropped, then one per this many."""
OUTCOMES_SHARE = 0.05
"""Once outcomes.jsonl holds this share of max_mb it is rewritten without the lines of removed events:
they outlive their recordings, and over months would fill the folder (then no capture fits)."""
_STALE = re.compile(rf"\.({re.escape(EVENT_PREFIX)}|{re.escape(IDLE_PREFIX)})[0-9-]+{re.escape(SUFFIX)}\.[a-z0-9_]{{8}}\.tmp")
_STOP = object()


class CaptureError(HandoverError):
    """A capture folder the daemon must not write (another user's, not a folder): one line, exit 2."""


def folder_problem(folder: str | os.PathLike) -> str | None:
    """Why ``capture.folder`` must not be used, or None. A folder another user owns or may write to is
    refused like the control socket's (runtime.control_access): they could plant recordings that
    ``handover train`` then learns from, or swap ours. A missing folder is checked where it would be made."""
    path = Path(folder)
    existing = next(p for p in (path, *path.parents) if p.exists() or p.is_symlink())
    if existing == path and not path.is_dir():
        return f"capture.folder {path} is not a folder; point it at a folder (it is created if missing)"
    why = untrusted_folder(existing)
    if not why and existing == path and os.stat(path).st_mode & 0o022:  # a sticky one too (/tmp): files planted
        why = f"folder {path} is writable by others"
    if why:
        return (f"capture.folder {path}: {why}: another user could change what `handover train` learns; choose a "
                "folder of this user's, e.g. /var/lib/handover/field (StateDirectory= in the unit file)")
    return None


def folder_unwritable(folder: str | os.PathLike) -> str | None:
    """Why this user cannot write ``capture.folder`` now (a read-only file system, no permission), or None:
    ``run --check`` warns; the daemon serves anyway (one line, then every capture is tried again)."""
    path = Path(folder)
    existing = next(p for p in (path, *path.parents) if p.exists())
    if os.access(existing, os.W_OK | os.X_OK):
        return None
    why = "is on a read-only file system" if os.statvfs(existing).f_flag & os.ST_RDONLY else "is not writable by this user"
    return (f"capture.folder {path}: {existing} {why}; captures would be lost while events are served (give the "
            "service user a folder, e.g. StateDirectory= in the unit file)")


@dataclass
class Capture:
    """One window or idle stretch the hot path copied out: frames, stamps, the file's stem and metadata."""

    stem: str
    frames: np.ndarray
    stamps: np.ndarray
    layout: SensorLayout
    meta: dict
    trial: dict | None = None
    """The Trial's fields of an event (None: an idle stretch)."""
    stretch: dict | None = None
    """An idle stretch's ``source`` and what else its entry in ``meta["idle_stretches"]`` holds."""


@dataclass
class Outcome:
    """One line of outcomes.jsonl (field_capture's layout)."""

    line: dict


class CaptureWriter:
    """Owns the capture folder (module docstring). ``start`` refuses an unsafe folder (CaptureError)."""

    def __init__(self, folder: str | os.PathLike, max_mb: float) -> None:
        self.folder = Path(folder)
        self.max_bytes = int(max_mb * 1e6)
        self.events = 0
        self.idle = 0
        self.outcomes = 0
        self.full = 0
        """Items the hot thread dropped: the queue was full, or too many windows waited (counted there only)."""
        self.lost = 0
        """Items the folder refused (counted on the writer's thread only)."""
        self.errors = 0
        self.bytes = 0
        self.removed = 0
        """Recordings removed to stay below ``max_bytes``."""
        self.problem: str | None = None
        """The folder's current problem (health holds it), None while writes work."""
        self._queue: queue.Queue = queue.Queue(QUEUE_ITEMS)
        self._files: dict[str, int] = {}
        """Our recordings in the folder and their sizes, by name."""
        self._thread: threading.Thread | None = None

    # -- the hot thread's side ----------------------------------------------------------------
    def put(self, item: Capture | Outcome) -> bool:
        """Hand ``item`` to the writer; never blocks (full: dropped, counted, a line per ``DROP_LOG_EVERY``)."""
        try:
            self._queue.put_nowait(item)
            return True
        except queue.Full:
            self.full += 1
            if self.full % DROP_LOG_EVERY == 1:
                log.warning("capture: the writer is behind (%d waiting); %d capture(s) dropped so far, events are "
                            "served as usual", QUEUE_ITEMS, self.full)
            return False

    @property
    def dropped(self) -> int:
        """Captures lost: dropped on the hot thread or refused by the folder."""
        return self.full + self.lost

    def counters(self) -> dict[str, int]:
        return {"capture_events": self.events, "capture_idle": self.idle, "capture_outcomes": self.outcomes,
                "capture_dropped": self.dropped, "capture_errors": self.errors, "capture_bytes": self.bytes}

    # -- lifetime -----------------------------------------------------------------------------
    def start(self) -> CaptureWriter:
        """Check (and make) the folder, remove stale temporary files, count what is there, start writing."""
        if problem := folder_problem(self.folder):
            raise CaptureError(problem)
        try:
            self.folder.mkdir(mode=0o755, parents=True, exist_ok=True)
            self._scan()
        except OSError as exc:  # read-only or full already: the daemon serves, the writer keeps trying
            self._failed(exc)
        self._thread = threading.Thread(target=self._loop, name="handover-capture", daemon=True)
        self._thread.start()
        log.info("capture: keeping decided windows and idle stretches in %s (at most %g MB)", self.folder,
                 self.max_bytes / 1e6)
        return self

    def stop(self, timeout: float = 2.0) -> None:
        """Write what is queued (within ``timeout``), then end the thread."""
        if self._thread is None:
            return
        with contextlib.suppress(queue.Full):
            self._queue.put(_STOP, timeout=timeout)
        self._thread.join(timeout)
        self._thread = None

    def _scan(self) -> None:
        """Stale temporary files (a kill -9 mid-write) removed; our recordings and text files counted."""
        with os.scandir(self.folder) as entries:
            for entry in entries:
                if not entry.is_file(follow_symlinks=False):
                    continue
                info = entry.stat(follow_symlinks=False)
                if _STALE.fullmatch(entry.name) and info.st_uid == os.geteuid():
                    with contextlib.suppress(FileNotFoundError):
                        os.unlink(entry.path)
                elif CAPTURED_NAME.fullmatch(entry.name) or entry.name in (OUTCOMES_FILE, LABELS_FILE):
                    self._files[entry.name] = info.st_size
        self.bytes = sum(self._files.values())

    # -- the writer thread --------------------------------------------------------------------
    def _loop(self) -> None:
        while (item := self._queue.get()) is not _STOP:
            try:
                self._write(item)
            except OSError as exc:
                self._failed(exc)
            except Exception as exc:  # a bug or a capture the format refuses: counted, never the end of the thread
                self.errors += 1
                self.lost += 1
                log.error("capture: %s not kept (%s: %s)", getattr(item, "stem", "outcome"), type(exc).__name__,
                          one_line(exc))
            else:
                self._worked()

    def _write(self, item: Capture | Outcome) -> None:
        if not self.folder.is_dir():  # never made again here: an unmounted disk's mount point would fill the root
            raise FileNotFoundError(errno.ENOENT, "the folder is gone (removed, or its disk unmounted); make it again")
        if self.problem is not None:  # it failed until now: count again what it holds
            self._files.clear()
            self._scan()
        if isinstance(item, Outcome):
            data = (json.dumps(item.line, allow_nan=False) + "\n").encode()
            self._make_room(len(data))
            fd = os.open(self.folder / OUTCOMES_FILE, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW
                         | os.O_NONBLOCK, 0o644)  # a FIFO there: ENXIO, one line, never a stuck writer
            try:
                os.write(fd, data)  # one write of one line: a kill -9 leaves whole lines or one cut last line
            finally:
                os.close(fd)
            self._files[OUTCOMES_FILE] = self._files.get(OUTCOMES_FILE, 0) + len(data)
            self.outcomes += 1
            if self._files[OUTCOMES_FILE] > OUTCOMES_SHARE * self.max_bytes:
                self._compact_outcomes()
        else:
            rec = _recording(item)
            name = item.stem + SUFFIX
            self._make_room(rec.frames.nbytes + rec.timestamps.nbytes + len(json.dumps(rec.meta)) + (64 << 10))
            size = rec.save(self.folder / name).stat().st_size
            self._files[name] = size
            if item.trial is None:
                self.idle += 1
            else:
                self.events += 1
        self.bytes = sum(self._files.values())

    def _compact_outcomes(self) -> None:
        """outcomes.jsonl keeps the lines of events still in the folder (a temp file renamed: never cut)."""
        path, temp = self.folder / OUTCOMES_FILE, self.folder / f".{OUTCOMES_FILE}.tmp"
        with open(path, "rb") as fh:
            kept = [line for line in fh if _event_of(line) + SUFFIX in self._files]
        with open(temp, "wb") as fh:
            fh.writelines(kept)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(temp, path)
        self._files[OUTCOMES_FILE] = sum(map(len, kept))

    def _make_room(self, incoming: int) -> None:
        """Remove the oldest recordings until ``incoming`` more bytes fit below ``max_bytes``; OSError (ENOSPC)
        when even an empty folder would not hold them."""
        oldest = sorted((n for n in self._files if CAPTURED_NAME.fullmatch(n)), key=lambda n: CAPTURED_NAME.fullmatch(n).group(2))
        while sum(self._files.values()) + incoming > self.max_bytes:
            if not oldest:
                raise OSError(28, f"a capture of {incoming / 1e6:.2f} MB does not fit in capture.max_mb "
                                  f"{self.max_bytes / 1e6:g} (raise it)")
            name = oldest.pop(0)
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.folder / name)
            del self._files[name]
            self.removed += 1

    def _failed(self, exc: OSError) -> None:
        self.errors += 1
        self.lost += 1
        if self.problem is None:
            self.problem = f"capture folder {self.folder}: {exc.strerror or one_line(exc)}; captures are lost until it takes files again"
            log.error("%s (events are served as usual; this is said once)", self.problem)

    def _worked(self) -> None:
        if self.problem is not None:
            self.problem = None
            log.warning("capture folder %s takes files again (%d capture(s) lost so far)", self.folder, self.lost)


def _event_of(line: bytes) -> str:
    """The event stem an outcomes.jsonl line is about ("" for a line that is none)."""
    try:
        event = json.loads(line)["event"]
    except (ValueError, KeyError, TypeError):
        return ""
    return event if isinstance(event, str) else ""


def _recording(item: Capture) -> Recording:
    """The recording of an event (one trial over all its frames) or of an idle stretch (all its frames)."""
    last = len(item.frames) - 1
    trials = [] if item.trial is None else [Trial(first=0, last=last, **item.trial)]
    meta = dict(item.meta)
    if item.stretch is not None:
        meta.update(idle_meta(len(item.frames), [{"index": 0, **item.stretch, "first": 0, "last": last}]))
    return Recording(item.layout, item.frames, item.stamps, trials, meta)
