"""The ground truth of an emulated session, as a file: what the person did, and when on the device clock.

``handover emulate --script-out FILE`` writes it; ``handover score EVENTS SCRIPT`` reads it. JSON lines:
a header (``type: "script"``, frame times from the first) and one ``type: "scripted"`` line per event
(its frame span, onset frame, action, subject, object, pose). A power cycle or stall fault shifts the
device clock off the recording's time: score sessions served without them.
"""

from __future__ import annotations

import json
import os
import stat
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path

import numpy as np

from firmware_io.errors import HandoverError
from firmware_io.recordings.bounded_zip import first_line, loads, quote
from firmware_io.recordings.recording import Recording, Trial, name_problem

__all__ = ["ScriptFileError", "SessionScript", "read_script", "session_script", "write_script"]

SCRIPT_VERSION = 1


class ScriptFileError(HandoverError, ValueError):
    """A script file that cannot be read (one line naming the file and the problem)."""


@dataclass(frozen=True)
class SessionScript:
    """A scripted session: its trials and how device time maps to its frames."""

    trials: list[Trial]
    frame_ms: np.ndarray
    clock_start_ms: int
    loop_ms: int | None
    synthetic: bool
    ended: bool = False
    """The emulator sent the whole session (``--no-loop``) before it wrote this: a scripted event no
    report answers was missed. Otherwise events after the last report may not have been played yet."""

    def frame_of(self, device_time_ms: int) -> tuple[int, int]:
        """(pass, frame) of the frame stamped ``device_time_ms``: the first frame at or after it
        (a stamp between two recorded times belongs to the later one)."""
        t = int(device_time_ms) - self.clock_start_ms
        loop = 0
        if self.loop_ms:
            loop, t = divmod(t, self.loop_ms)
        return loop, int(np.searchsorted(self.frame_ms, t, side="left"))


def session_script(recording: Recording, clock_start_ms: int = 0, loop: bool = False) -> SessionScript:
    """The script of ``recording`` served from power-on with the clock starting at ``clock_start_ms``."""
    ms = np.round((recording.timestamps - recording.timestamps[0]) * 1000.0).astype(np.int64)
    loop_ms = int(ms[-1] + round(recording.period_s() * 1000)) if loop else None
    return SessionScript(list(recording.trials), ms, int(clock_start_ms), loop_ms,
                         bool(recording.meta.get("synthetic", False)))


def write_script(path: str | os.PathLike, recording: Recording, clock_start_ms: int = 0, loop: bool = False,
                 source: str = "", started: bool = True, ended: bool = False) -> int:
    """Write the script of ``recording`` to ``path`` (atomically: a reader never sees half a file);
    returns the number of scripted events. ``started``: ``clock_start_ms`` is known (the device time
    of the session's first frame); a script written before is refused by ``read_script``. ``ended``:
    every frame of a non-looping session has been sent."""
    script = session_script(recording, clock_start_ms, loop)
    header = {"type": "script", "protocol": SCRIPT_VERSION, "started": bool(started), "ended": bool(ended), "source": source,
              "synthetic": script.synthetic,
              "clock_start_ms": script.clock_start_ms, "loop_ms": script.loop_ms, "frames": len(script.frame_ms),
              "frame_ms": script.frame_ms.tolist()}
    lines = [json.dumps(header)]
    for k, t in enumerate(script.trials):
        lines.append(json.dumps({"type": "scripted", "event": k + 1, "onset_frame": int(t.extra.get("onset", t.first)),
                                 "action": t.action, "subject": t.subject, "object": t.object, "pose": t.pose,
                                 "first_frame": t.first, "last_frame": t.last,
                                 "time_s": t.extra.get("onset_s")}))
    p = Path(path)
    tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp")
    try:
        tmp.write_text("\n".join(lines) + "\n")
        os.replace(tmp, p)
    except OSError:  # e.g. FILE names a folder: leave nothing behind
        tmp.unlink(missing_ok=True)
        raise
    return len(script.trials)


MAX_SCRIPT_BYTES = 16 << 20
"""A script's size: a 9-hour session's frame times take about 10 MB; more is no script we wrote."""
MAX_SCRIPT_EVENTS = 10_000
"""Scripted events in one script: the demo has 40, a recorded session a few hundred, and a 9-hour session
(the size cap's) with a handover every 4 s about 8,000. Each is scored once per pass, so this bounds score's
work (a bomb beyond it: ./dev bench hostile, case 15)."""


def read_script(path: str | os.PathLike) -> SessionScript:
    """The script ``write_script`` wrote; ScriptFileError with one line when it is not one (checked against
    what ``write_script`` writes: a hand-edited or hostile file is refused, never scored or echoed)."""
    p = Path(path)
    again = "; write it again with handover emulate --script-out"
    try:
        with open(p, "rb") as fh:
            if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
                raise ScriptFileError(f"{p}: not a regular file; give the file handover emulate --script-out wrote")
            data = fh.read(MAX_SCRIPT_BYTES + 1)
    except OSError as exc:
        raise ScriptFileError(f"{p}: cannot read ({exc.strerror or exc})") from None
    if len(data) > MAX_SCRIPT_BYTES:
        raise ScriptFileError(f"{p}: over {MAX_SCRIPT_BYTES >> 20} MiB, larger than any script handover writes")
    try:
        rows = [loads(line) for line in data.decode("utf-8").splitlines() if line.strip()]
    except ValueError as exc:
        raise ScriptFileError(f"{p}: not JSON lines ({first_line(exc)}); give the file handover emulate --script-out "
                              "wrote") from None
    if not rows or not isinstance(rows[0], dict) or rows[0].get("type") != "script":
        raise ScriptFileError(f"{p}: no script header; give the file handover emulate --script-out wrote")
    head = rows[0]
    if head.get("protocol") != SCRIPT_VERSION:
        raise ScriptFileError(f"{p}: script version {quote(head.get('protocol'))}, this handover reads {SCRIPT_VERSION}")
    if head.get("started") is False:
        raise ScriptFileError(f"{p}: no host asked the emulator for frames yet, so the session's device times are "
                              "not known; score once the daemon has read the session")
    events = [r for r in rows[1:] if isinstance(r, dict) and r.get("type") == "scripted"]
    if len(events) > MAX_SCRIPT_EVENTS:
        raise ScriptFileError(f"{p}: {len(events)} scripted events, more than any session handover scripts "
                              f"(at most {MAX_SCRIPT_EVENTS}){again}")
    if problem := (_header_problem(head) or next(filter(None, (_event_problem(r, head) for r in events)), None)
                   or _order_problem(events)):
        raise ScriptFileError(f"{p}: {problem}{again}")
    trials = [Trial(subject=r["subject"], object=r["object"], pose=r["pose"], action=r["action"], run=r["event"],
                    first=r["first_frame"], last=r["last_frame"], extra={"onset": r["onset_frame"]}) for r in events]
    return SessionScript(trials, np.asarray(head["frame_ms"], dtype=np.int64), head["clock_start_ms"],
                         head.get("loop_ms"), bool(head.get("synthetic")), ended=head.get("ended") is True)


def _count(value: object, low: int = 0) -> bool:
    """An integer ``write_script`` could have written: not a bool, a float or beyond int64."""
    return type(value) is int and low <= value < 2**62


def _header_problem(head: dict) -> str | None:
    ms = head.get("frame_ms")
    if not isinstance(ms, list) or not ms or not all(_count(m) for m in ms) or ms[0] != 0:
        return "frame_ms must list the frames' times: whole ms from the first frame (0)"
    if any(b < a for a, b in pairwise(ms)):
        return "frame_ms goes back in time; a script's frame times never descend"
    if not _count(head.get("clock_start_ms")):
        return f"clock_start_ms {quote(head.get('clock_start_ms'))} is not a device time in whole ms"
    loop_ms = head.get("loop_ms")
    if loop_ms is not None and (not _count(loop_ms) or loop_ms <= ms[-1]):  # else each ms would be a pass
        return f"loop_ms {quote(loop_ms)} must be whole ms longer than the session ({ms[-1]} ms)"
    return None


def _event_problem(row: dict, head: dict) -> str | None:
    n = len(head["frame_ms"])
    where = f"scripted event {quote(row.get('event'))}"
    if bad := next(filter(None, (name_problem(k, row.get(k)) for k in ("action", "subject", "object", "pose"))), None):
        return f"{where}: {bad}"
    if not _count(row.get("event"), 1):
        return f"{where}: its number must be a whole number from 1"
    frames = [row.get(k) for k in ("first_frame", "onset_frame", "last_frame")]
    if not all(_count(f) and f < n for f in frames):
        return f"{where}: first, onset and last frame must be whole frames of the session (0..{n - 1})"
    if frames[0] > frames[2]:
        return f"{where}: its first frame {frames[0]} is after its last {frames[2]}"
    return None


def _order_problem(events: list[dict]) -> str | None:
    """``write_script`` numbers a recording's trials 1, 2, ... in time order, and the scoring rule gives
    each report to the one event whose span holds it: numbers repeat or spans overlap only in a made-up file."""
    seen: set[int] = set()
    for r in events:
        if r["event"] in seen:
            return f"scripted event {r['event']} appears twice"
        seen.add(r["event"])
    for a, b in pairwise(events):
        if b["first_frame"] <= a["last_frame"]:
            return (f"scripted event {b['event']} (frames {b['first_frame']}..{b['last_frame']}) starts before event "
                    f"{a['event']} ends (frames {a['first_frame']}..{a['last_frame']}); a session's events follow "
                    "one another")
    return None
