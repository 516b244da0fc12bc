"""Recording a subject's idle stretches: the plan's stretches the file lacks, each saved the moment it ends.

Same rules as the trials (``record_session``): the subject's file is the only state, so a
stopped session resumes with the stretches it lacks; a stretch during which the link dropped is
recorded again. The recorder says what to do at the start of each stretch ("move the arm now")
and cues a listener (a scripted subject) with ``cue("idle", slot)``. numpy only.
"""

from __future__ import annotations

from collections.abc import Sequence

from firmware_io.recordings import arm_marks
from firmware_io.recordings.idle_stretches import IdleSlot
from firmware_io.recordings.record_session import SessionIO, SessionOptions, SessionResult, SessionStore, _now
from firmware_io.recordings.trial_capture import capture_trial, drain


def run_idle(client, store: SessionStore, plan: Sequence[IdleSlot], opts: SessionOptions, io: SessionIO,
             session_info: dict | None = None) -> SessionResult:
    """Record every stretch of ``plan`` the store lacks. The client must be open and streaming."""
    todo = store.remaining_idle(plan)
    result = SessionResult(planned=len(plan), done=len(plan) - len(todo))
    if not todo:
        return result
    store.meta.setdefault("sessions", []).append(
        {"started": _now(), "idle_plan": [[s.source, s.seconds] for s in plan], "auto": opts.auto,
         **(session_info or {})})
    session_no = len(store.meta["sessions"])
    total = sum(s.seconds for s in todo)
    io.show(f"{result.done} of {len(plan)} idle stretches already in {store.path}; {len(todo)} to record "
            f"({total / 60:.1f} min): nobody touches the object during them")
    for slot in todo:
        outcome = _record_stretch(client, store, slot, opts, io, result, session_no)
        if outcome == "quit":
            result.stopped = "quit"
            return result
    result.stopped = "complete" if result.complete else "skipped"
    return result


def _record_stretch(client, store: SessionStore, slot: IdleSlot, opts: SessionOptions, io: SessionIO,
                    result: SessionResult, session_no: int) -> str:
    """One stretch until it is kept, skipped or the investigator quits: 'kept', 'skipped' or 'quit'."""
    attempt = 0
    while True:
        attempt += 1
        io.say(f"Idle {result.done + 1} of {result.planned}: {slot.describe()}. Next: {slot.prompt}")
        if opts.auto:
            io.sleep(min(opts.gap_seconds, 1.0))
        elif (stop := io.ask_to_start("skipped")) is not None:
            return stop
        drain(client)
        annotations: dict = {}

        def go(slot: IdleSlot = slot, annotations: dict = annotations) -> None:
            io.say(f"Now: {slot.prompt}")
            annotations.update(io.cue("idle", slot) or {})

        capture = capture_trial(client, slot.seconds, go=go)
        io.say("Stop.")
        if capture.reconnected:
            io.show("the device reconnected during this stretch; recording it again")
            continue
        extra = {"attempt": attempt, "session": session_no, "recorded_at": _now(), "frame_gaps": capture.gaps,
                 "device_ms": int(capture.device_ms[0]) if len(capture.device_ms) else None, **annotations}
        if opts.arm_log is not None and (marks := opts.arm_log.marks_for(capture.received)):
            extra[arm_marks.KEY] = marks
        store.add_idle(slot, capture.frames, capture.stamps, extra)
        result.recorded += 1
        result.done += 1
        io.show(f"idle stretch {slot.index + 1} saved ({len(capture.frames)} frames, {slot.source})")
        if opts.auto:
            return "kept"
        answer = io.ask("Enter = keep, r = redo, q = quit", ("", "r", "q"))
        if answer == "r":
            store.remove_last()
            result.done -= 1
            continue
        return "quit" if answer == "q" else "kept"


__all__ = ["run_idle"]
