"""Recording a subject session the paper's way: the plan, capture, trigger check (the file: ``session_store``).

Poses x objects x actions x runs (paper: 3 x 3 x 4 x 5 = 180 trials of 3 s). Each trial is the held
grasp before the go cue plus the trial after it (``trial_capture``), written the moment it ends; a
resumed session records the slots the file lacks. Prompting goes through ``SessionIO``, so the same
loop runs from a terminal, a script (``--auto``) and tests. numpy only.
"""

from __future__ import annotations

import datetime as _dt
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from firmware_io.layout import SensorLayout
from firmware_io.recordings import arm_marks
from firmware_io.recordings.recording import ACTIONS, Recording, RecordingError
from firmware_io.recordings.session_store import (
    NAME_PATTERN,
    NotSaved,
    SessionError,
    SessionStore,
    recording_path,
    subject_problem,
)
from firmware_io.recordings.trial_capture import LEAD_IN_SECONDS, DeviceLost, capture_trial, drain
from firmware_io.trigger_level import PAPER_FRACTION, is_trigger_level

POSES = ("down", "up", "horizontal")
OBJECTS = ("ball", "cylinder", "plank")
RECORD_OUT = "recordings"
"""Where ``handover record`` writes by default (train names it when it is not given as --data)."""
DEFAULT_RUNS = 5
MAX_RUNS = 100
"""The most runs of each pose, object and action: 3600 trials of the default protocol, days of recording (the
plan is listed before the first trial, so --runs 100000000 never started)."""


@dataclass(frozen=True, order=True)
class TrialSlot:
    """One cell of the protocol: what the subject does in one trial."""

    pose: str
    object: str
    action: str
    run: int

    @property
    def key(self) -> tuple[str, str, str, int]:
        return (self.pose, self.object, self.action, self.run)

    def describe(self) -> str:
        return f"pose {self.pose}, object {self.object}, action {self.action.upper()}, run {self.run}"


@dataclass(frozen=True)
class ProtocolPlan:
    """Which trials a session holds, in the order they are recorded (pose, object, action, run)."""

    poses: tuple[str, ...] = POSES
    objects: tuple[str, ...] = OBJECTS
    actions: tuple[str, ...] = ACTIONS
    runs: int = DEFAULT_RUNS

    def __post_init__(self) -> None:
        for kind, names in (("pose", self.poses), ("object", self.objects), ("action", self.actions)):
            if not names:
                raise SessionError(f"the protocol needs at least one {kind}")
            bad = [n for n in names if not NAME_PATTERN.fullmatch(n)]
            if bad:
                raise SessionError(f"{kind} name {bad[0]!r}: use letters, digits, '_', '-' or '.'")
            if len(set(names)) != len(names):
                raise SessionError(f"a {kind} is listed twice: {', '.join(names)}")
        if not 1 <= self.runs <= MAX_RUNS:
            raise SessionError(f"runs must be from 1 to {MAX_RUNS}, got {self.runs}")

    @classmethod
    def from_text(cls, poses: str, objects: str, actions: str, runs: int) -> ProtocolPlan:
        """Comma-separated names as given on a command line."""
        def split(text: str) -> tuple[str, ...]:
            return tuple(p.strip() for p in text.split(",") if p.strip())
        return cls(split(poses), split(objects), split(actions), int(runs))

    def slots(self) -> list[TrialSlot]:
        return [
            TrialSlot(p, o, a, r)
            for p in self.poses
            for o in self.objects
            for a in self.actions
            for r in range(1, self.runs + 1)
        ]

    def to_dict(self) -> dict:
        return {"poses": list(self.poses), "objects": list(self.objects), "actions": list(self.actions),
                "runs": self.runs}


# -- trigger check ----------------------------------------------------------------------------
@dataclass(frozen=True)
class TriggerCheck:
    """Did any taxel of the watched pads reach the trigger level (the paper's 15 % of full scale)?"""

    triggered: bool
    first_frame: int
    peak: int
    level: float
    fullscale: float

    @property
    def peak_fraction(self) -> float:
        return self.peak / self.fullscale if self.fullscale else 0.0


def check_trigger(frames: np.ndarray, layout: SensorLayout, pads: str | Sequence[int] = "all",
                  fraction: float = PAPER_FRACTION) -> TriggerCheck:
    """The same rule as the trainer's data set assembly: first frame whose max reaches the level."""
    if not is_trigger_level(fraction):
        raise SessionError(f"trigger fraction must be in (0, 1), got {fraction}")
    idx = layout.pads(pads)
    fullscale = max(layout.matrices[p].fullscale for p in idx)
    level = fraction * fullscale
    sel = np.asarray(frames)[:, layout.columns(idx)]
    if sel.size == 0:
        return TriggerCheck(False, -1, 0, level, fullscale)
    row_max = sel.max(axis=1)
    hits = np.flatnonzero(row_max >= level)
    return TriggerCheck(bool(len(hits)), int(hits[0]) if len(hits) else -1, int(row_max.max()), level, fullscale)


# -- the session loop -------------------------------------------------------------------------
@dataclass
class SessionIO:
    """How the loop talks to people and to scripted subjects.

    ``say``: an instruction for the subject/investigator (screen, maybe voice);
    ``show``: information for the investigator only (quick look, file status);
    ``ask(question, choices)``: one of ``choices`` (first = default), or None (no prompts, auto);
    ``cue(kind, slot)``: "prepare", "go", "stop" for listeners such as a scripted subject;
    it may return a dict of annotations stored with the trial (e.g. a simulator's onset).
    """

    say: Callable[[str], None] = lambda text: None
    show: Callable[[str], None] = lambda text: None
    ask: Callable[[str, Sequence[str]], str | None] = lambda q, c: None
    cue: Callable[[str, TrialSlot], dict | None] = lambda kind, slot: None
    sleep: Callable[[float], None] = time.sleep

    def ask_to_start(self, skipped: str) -> str | None:
        """Before a recording (a trial or an idle stretch, in the same words): None to start it,
        ``skipped`` to pass it over, 'quit' to stop the session; no answer (auto) starts it."""
        answer = self.ask("Enter = start, s = skip, q = quit", ("", "s", "q"))
        return {"s": skipped, "q": "quit"}.get(answer)


DEFAULT_TRIAL_SECONDS = 3.0
MIN_TRIAL_SECONDS = 0.3
"""A trial must be longer: the action needs a window of frames after the go cue."""
MAX_SPAN_SECONDS = 600.0
"""The longest trial, lead-in, gap or countdown: ten minutes is already a typo, not a protocol."""


@dataclass
class SessionOptions:
    trial_seconds: float = DEFAULT_TRIAL_SECONDS
    """recorded after the go cue (the person's reaction and action)."""
    lead_in_seconds: float = LEAD_IN_SECONDS
    """recorded before the go cue (the held grasp every trigger needs before the action)."""
    gap_seconds: float = 2.0
    """auto mode: pause before each go (the investigator re-places the object)."""
    countdown: int = 3
    """interactive mode: seconds counted down aloud before go."""
    fraction: float = PAPER_FRACTION
    """the paper's trigger level: each trial's peak is stored against it."""
    pads: str = "all"
    case_check: Callable[[np.ndarray, np.ndarray, SensorLayout], tuple[int, str | None]] | None = None
    """(frames, stamps, layout) -> (the frame training's trigger cuts at, None), else (-1, why training gets
    no case) (``handover record`` passes ``trainer.dataset.case_check``); None: the paper's level decides."""
    auto: bool = False
    retries: int = 1
    """auto mode: how often a trial that gives training no case is recorded again before it is kept flagged."""
    max_trials: int | None = None
    """stop after this many trials (scripted partial sessions)."""
    arm_log: arm_marks.ArmMarkLog | None = None
    """what the robot says about its arm (``--control``): its marks are stored with each trial and stretch."""
    quick_look: Callable[[np.ndarray, SensorLayout, int], str] | None = None
    """(frames, layout, the stored ``trigger_frame``) -> what the investigator sees after each trial."""

    def __post_init__(self) -> None:
        """Every span a number of seconds a session can wait out: NaN and infinity passed ``<= 0`` checks
        and hung the first trial (lead-in), or ended in a traceback (trial seconds)."""
        for name, value, low, flag in (("trial seconds", self.trial_seconds, MIN_TRIAL_SECONDS, "--trial-seconds"),
                                       ("lead-in", self.lead_in_seconds, 0.0, "--lead-in"),
                                       ("gap", self.gap_seconds, 0.0, "--gap"), ("countdown", self.countdown, 0, "--countdown")):
            if not (low < value if name == "trial seconds" else low <= value) or not value <= MAX_SPAN_SECONDS:
                above = f"more than {low:g}" if name == "trial seconds" else f"at least {low:g}"
                raise SessionError(f"{flag}: the {name} must be {above} and at most {MAX_SPAN_SECONDS:g} seconds, "
                                   f"got {value}")
        if self.retries < 0:
            raise SessionError(f"--retries must be at least 0, got {self.retries}")
        if self.max_trials is not None and self.max_trials < 1:  # 0 or less recorded nothing and said "saved in"
            raise SessionError(f"--max-trials must be at least 1, got {self.max_trials}")


@dataclass
class SessionResult:
    """What a session of trials or of idle stretches did (``planned``, ``done``: slots; ``recorded``: this run)."""

    planned: int
    done: int
    recorded: int = 0
    flagged: list[int] = field(default_factory=list)
    stopped: str = "complete"

    @property
    def complete(self) -> bool:
        return self.done >= self.planned


def run_session(client, store: SessionStore, plan: ProtocolPlan, opts: SessionOptions, io: SessionIO,
                session_info: dict | None = None) -> SessionResult:
    """Record every slot of ``plan`` the store lacks. The client must be open and streaming."""
    check_trigger(np.zeros((1, store.layout.n_taxels), np.uint16), store.layout, opts.pads, opts.fraction)
    store.meta.setdefault("sessions", []).append(
        {"started": _now(), "protocol": plan.to_dict(), "trial_seconds": opts.trial_seconds,
         "lead_in_seconds": opts.lead_in_seconds,
         "trigger_fraction": opts.fraction, "pads": opts.pads, "auto": opts.auto, **(session_info or {})})
    session_no = len(store.meta["sessions"])
    todo = store.remaining(plan)
    planned = len(plan.slots())
    result = SessionResult(planned=planned, done=planned - len(todo))
    if not todo:
        result.stopped = "complete"
        return result
    io.show(f"{result.done} of {planned} trials already in {store.path}; {len(todo)} to record")
    for slot in todo:
        if opts.max_trials is not None and result.recorded >= opts.max_trials:
            result.stopped = "max_trials"
            return result
        outcome = _record_slot(client, store, slot, opts, io, result, session_no)
        if outcome in ("kept", "kept_quit"):
            result.done += 1
        if outcome in ("quit", "kept_quit"):
            result.stopped = "quit"
            return result
    result.stopped = "complete" if result.done >= planned else "skipped"
    return result


def _record_slot(client, store: SessionStore, slot: TrialSlot, opts: SessionOptions, io: SessionIO,
                 result: SessionResult, session_no: int) -> str:
    """One slot until it is kept, discarded or the investigator quits.

    Returns 'kept', 'discarded', 'quit' (before recording) or 'kept_quit' (kept, then quit)."""
    attempt = 0
    while True:
        attempt += 1
        n = store.n_trials + 1
        io.say(f"Trial {result.done + 1} of {result.planned}: {slot.describe()}. Place the {slot.object}, hand {slot.pose}.")
        io.cue("prepare", slot)
        if opts.auto:
            io.sleep(opts.gap_seconds)
        else:
            if (stop := io.ask_to_start("discarded")) is not None:
                return stop
            for k in range(opts.countdown, 0, -1):
                io.say(str(k))
                io.sleep(1.0)
        drain(client)
        annotations: dict = {}

        def go(slot: TrialSlot = slot, annotations: dict = annotations) -> None:
            io.say(f"Go: {slot.action}!")
            annotations.update(io.cue("go", slot) or {})

        capture = capture_trial(client, opts.trial_seconds, lead_in=opts.lead_in_seconds, go=go)
        io.cue("stop", slot)
        io.say("Stop.")
        if capture.reconnected:
            io.show("the device reconnected during this trial; recording it again")
            continue
        check = check_trigger(capture.frames, store.layout, opts.pads, opts.fraction)
        trigger_frame, no_case = (
            opts.case_check(capture.frames, capture.stamps, store.layout) if opts.case_check is not None
            else (check.first_frame, None if check.triggered else f"never reached {opts.fraction:.0%} of full scale"))
        extra = {
            "no_case": no_case, "triggered": check.triggered, "trigger_frame": trigger_frame, "peak": check.peak,
            "peak_fraction": round(check.peak_fraction, 4), "trigger_fraction": opts.fraction,
            "device_ms": int(capture.device_ms[0]), "frame_gaps": capture.gaps, "attempt": attempt,
            "session": session_no, "recorded_at": _now(), **annotations, "go_frame": capture.go_frame,
            "lead_in_s": opts.lead_in_seconds,
        }
        if opts.case_check is not None:
            extra["case_cut"] = str(opts.case_check)  # which cut decided no_case
        if opts.arm_log is not None and (marks := opts.arm_log.marks_for(capture.received)):
            extra[arm_marks.KEY] = marks
        if isinstance(annotations.get("onset"), int) and annotations["onset"] >= 0:
            extra["onset"] = annotations["onset"] + capture.go_frame  # the cue's onset counts from go
        index = store.add(slot, capture.frames, capture.stamps, extra)
        result.recorded += 1
        if opts.quick_look is not None:
            io.show(opts.quick_look(capture.frames, store.layout, trigger_frame))
        status = (f"trial {n} saved ({len(capture.frames)} frames, peak {check.peak_fraction:.0%} of full scale)")
        io.show(status)
        if no_case is not None:
            io.show(f"!! training gets no case from this trial ({no_case}); redo it if the person did not act")
        if opts.auto:
            if no_case is not None and attempt <= opts.retries:
                store.remove_last()
                continue
            if no_case is not None:
                result.flagged.append(index)
            return "kept"
        answer = io.ask("Enter = keep, r = redo, d = discard, q = quit" if no_case is None
                        else "r = redo (suggested), Enter = keep anyway, d = discard, q = quit", ("", "r", "d", "q"))
        if answer == "r":
            store.remove_last()
            continue
        if answer == "d":
            store.remove_last()
            return "discarded"
        if no_case is not None:
            result.flagged.append(index)
        return "kept_quit" if answer == "q" else "kept"


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


def flagged_trials(rec: Recording) -> list[int]:
    """Indices of trials the recorder flagged: training gets no case from them (files written before
    ``no_case`` was stored: the paper's level was never reached)."""
    return [i for i, t in enumerate(rec.trials)
            if (t.extra["no_case"] is not None if "no_case" in t.extra else t.extra.get("triggered") is False)]


__all__ = [
    "RECORD_OUT", "DeviceLost", "NotSaved", "ProtocolPlan", "RecordingError", "SessionError", "SessionIO", "SessionOptions",
    "SessionResult", "SessionStore", "TrialSlot", "capture_trial", "check_trigger", "drain", "flagged_trials",
    "recording_path", "run_session", "subject_problem"
]
