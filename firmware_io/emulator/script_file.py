"""The ground truth of an emulated session, as a file: what the person did, and when on the device clock.

``handover emulate --script-out FILE`` writes it (again when a host first asks for frames: the
session starts then); ``handover score EVENTS SCRIPT`` reads it to score a captured event stream. JSON lines: a header (``type: "script"``) with each frame's time
in ms from the first (device time = ``clock_start_ms`` + that, plus one ``loop_ms`` per pass
when the session repeats), then one ``type: "scripted"`` line per event: the frame span the
event can be answered in (``first_frame`` .. ``last_frame``, the object placed .. taken away),
its ``onset_frame``, the ``action`` and who did it (``subject``, ``object``, ``pose``).

The device clock matches the recording's own time until the controller is power-cycled or a
stall fault shifts the two (the emulator's ``disconnect`` and ``stall`` faults): score a
session served without those.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from firmware_io.recordings.recording import Recording, Trial

__all__ = ["ScriptFileError", "SessionScript", "read_script", "session_script", "write_script"]

SCRIPT_VERSION = 1


class ScriptFileError(ValueError):
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


def read_script(path: str | os.PathLike) -> SessionScript:
    """The script ``write_script`` wrote; ScriptFileError with one line when it is not one."""
    p = Path(path)
    try:
        rows = [json.loads(line) for line in p.read_text().splitlines() if line.strip()]
    except OSError as exc:
        raise ScriptFileError(f"{p}: cannot read ({exc.strerror or exc})") from None
    except ValueError as exc:
        raise ScriptFileError(f"{p}: not JSON lines ({exc}); give the file handover emulate --script-out wrote") from None
    if not rows or not isinstance(rows[0], dict) or rows[0].get("type") != "script":
        raise ScriptFileError(f"{p}: no script header; give the file handover emulate --script-out wrote")
    head = rows[0]
    if head.get("protocol") != SCRIPT_VERSION:
        raise ScriptFileError(f"{p}: script version {head.get('protocol')!r}, this handover reads {SCRIPT_VERSION}")
    if head.get("started") is False:
        raise ScriptFileError(f"{p}: no host asked the emulator for frames yet, so the session's device times are "
                              "not known; score once the daemon has read the session")
    try:
        trials = [Trial(subject=str(r["subject"]), object=str(r["object"]), pose=str(r["pose"]), action=str(r["action"]),
                        run=int(r["event"]), first=int(r["first_frame"]), last=int(r["last_frame"]),
                        extra={"onset": int(r["onset_frame"])})
                  for r in rows[1:] if isinstance(r, dict) and r.get("type") == "scripted"]
        frame_ms = np.asarray(head["frame_ms"], dtype=np.int64)
        loop_ms = None if head.get("loop_ms") is None else int(head["loop_ms"])
        script = SessionScript(trials, frame_ms, int(head["clock_start_ms"]), loop_ms, bool(head.get("synthetic")),
                               ended=head.get("ended") is True)
    except (KeyError, TypeError, ValueError, OverflowError) as exc:  # OverflowError: 1e400, a 30-digit number
        raise ScriptFileError(f"{p}: a script line lacks or garbles {exc}; write it again with handover emulate "
                              "--script-out") from None
    if problem := _script_problem(script):
        raise ScriptFileError(f"{p}: {problem}; write it again with handover emulate --script-out")
    return script


def _script_problem(script: SessionScript) -> str | None:
    """What no ``write_script`` writes (a hand-edited or damaged file), or None."""
    ms = script.frame_ms
    if ms.ndim != 1 or not len(ms):
        return "frame_ms must list the frames' times in ms from the first"
    if script.loop_ms is not None and script.loop_ms <= int(ms[-1]):  # else each ms would be a pass
        return f"loop_ms {script.loop_ms} must be longer than the session ({int(ms[-1])} ms)"
    return None
