"""``handover record``: walk a subject through the paper's protocol and record every trial.

Instructions go to the terminal and, when espeak-ng is installed, to the loudspeaker (the
subject should not have to read a screen while acting). Each trial is saved the moment it
ends; running the same command again continues where the session stopped.
"""

from __future__ import annotations

import argparse
import math
import shutil
import subprocess
import sys

from firmware_io.commands.options import out_folder, trigger_level
from firmware_io.errors import DeviceFailure, HandoverError, Interrupted
from firmware_io.recordings.idle_stretches import DEFAULT_IDLE_MINUTES
from firmware_io.recordings.record_session import DEFAULT_RUNS, OBJECTS, POSES, RECORD_OUT
from firmware_io.recordings.recording import ACTIONS
from firmware_io.recordings.trial_capture import LEAD_IN_SECONDS
from firmware_io.transports.tcp import URL_FORM
from firmware_io.trigger_level import PAPER_FRACTION

__all__ = ["add_arguments", "main"]

IDLE_ONLY_MINUTES = 20.0
"""``--idle-only`` without ``--idle-minutes``: a long idle session."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--device", required=True,
                        help=f"device URL: serial:///dev/ttyUSB0, {URL_FORM}, ... or subject://?seed=0 "
                             "(emulated controller with a scripted simulated subject; synthetic data)")
    parser.add_argument("--subject", required=True, help="subject id (the file is OUT/subject_ID.hrec)")
    parser.add_argument("--out", default=RECORD_OUT, help=f"folder of the recordings (default ./{RECORD_OUT})")
    parser.add_argument("--poses", default=",".join(POSES), help="comma-separated hand poses")
    parser.add_argument("--objects", default=",".join(OBJECTS), help="comma-separated objects")
    parser.add_argument("--actions", default=",".join(ACTIONS), help="comma-separated actions")
    parser.add_argument("--runs", type=int, default=DEFAULT_RUNS, help="runs of each pose/object/action")
    parser.add_argument("--trial-seconds", type=float, default=3.0, help="recorded after the go cue (paper: 3 s)")
    parser.add_argument("--lead-in", type=float, default=LEAD_IN_SECONDS,
                        help=f"recorded before the go cue: the held grasp the triggers need (default {LEAD_IN_SECONDS:g} s)")
    parser.add_argument("--gap", type=float, default=2.0, help="--auto: pause before each trial (seconds)")
    parser.add_argument("--countdown", type=int, default=3, help="seconds counted down before go")
    parser.add_argument("--fraction", type=trigger_level, default=None,
                        help="check each trial against the paper's threshold trigger at this level (paper: "
                             f"{PAPER_FRACTION}), as `handover train --fraction` cuts; default: the trigger "
                             "`handover train` cuts with by default")
    parser.add_argument("--pads", default="all", help="pads watched by the trigger check (all, distal, 1,3,5 ...)")
    parser.add_argument("--auto", action="store_true",
                        help="no prompts, fixed timing (scripted sessions, tests); a trial that gives training no "
                             "case is recorded again --retries times, then kept flagged")
    parser.add_argument("--retries", type=int, default=1, help="--auto: repeats of a trial that gives no case")
    parser.add_argument("--max-trials", type=int, default=None, help="stop after this many trial attempts (a trial recorded again counts again)")
    parser.add_argument("--idle-minutes", type=float, default=None,
                        help=f"idle recorded after the trials: the object held still, the arm moving, regrasps, the "
                             f"hand closing and opening, nobody touching it; what a model needs to stay quiet "
                             f"(default {DEFAULT_IDLE_MINUTES:g} min, {IDLE_ONLY_MINUTES:g} with --idle-only; 0: none)")
    parser.add_argument("--idle-only", action="store_true",
                        help="record idle stretches only (a long idle session; no trials)")
    parser.add_argument("--control", default=None, metavar="SOCKET",
                        help="Unix datagram socket (path or @name) on which the robot says 'arm moving' / 'arm still', "
                             "as to the daemon's [control] socket; the marks are stored with the recording")
    parser.add_argument("--quiet", action="store_true", help="no voice (espeak-ng); with --auto also no lines per "
                        "trial or stretch, the final summary line only (a prompted session still shows its instructions)")
    parser.add_argument("--no-look", action="store_true", help="no per-pad sparklines after each trial")


class Voice:
    """espeak-ng in the background: never blocks the session, silently absent when not installed."""

    def __init__(self, enabled: bool) -> None:
        self.exe = shutil.which("espeak-ng") if enabled else None
        self._proc: subprocess.Popen | None = None

    def say(self, text: str) -> None:
        if not self.exe:
            return
        if self._proc is not None and self._proc.poll() is None:
            self._proc.terminate()  # the newest instruction matters more than the rest of the old one
        try:
            self._proc = subprocess.Popen([self.exe, text], stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                          stderr=subprocess.DEVNULL)
        except OSError:
            self.exe = None

    def close(self) -> None:
        if self._proc is not None and self._proc.poll() is None:
            try:
                self._proc.wait(timeout=3)
            except subprocess.TimeoutExpired:
                self._proc.kill()


def _ask(question: str, choices) -> str:
    """One answer from stdin; end of input means quit (a script that ran out of answers)."""
    for _ in range(5):
        print(f"{question} > ", end="", flush=True)
        line = sys.stdin.readline()
        if not line:
            print()
            return "q"
        answer = line.strip().lower()
        if answer in choices:
            return answer
        print(f"  please answer one of: {', '.join(c or 'Enter' for c in choices)}")
    return "q"


def main(args: argparse.Namespace) -> int:
    from firmware_io.recordings.idle_stretches import idle_plan
    from firmware_io.recordings.record_session import subject_problem
    from firmware_io.transports.base import TransportError

    plan, opts = _plan_and_options(args)  # a SessionError for a bad pose, object or action list
    if problem := subject_problem(args.subject):  # before the device opens
        raise HandoverError(problem)
    try:
        idle_plan(idle_minutes(args))
    except ValueError as exc:
        raise HandoverError(f"--idle-minutes: {exc}") from None
    if args.idle_only and idle_minutes(args) == 0:
        raise HandoverError("--idle-only with --idle-minutes 0 records nothing: give the minutes of idle to record")
    out_folder(args.out)
    try:
        client, subject = _connect(args.device, args.trial_seconds)
    except TransportError as exc:  # a URL that can never open: the user's (exit 2), even an absent device's
        raise HandoverError(str(exc)) from None
    voice = Voice(enabled=not args.quiet)
    try:
        control = _listen(args.control, opts)
    except OSError as exc:
        client.close()
        raise HandoverError(str(exc)) from None
    try:
        return _record(args, client, subject, plan, opts, voice)
    finally:
        client.close()
        voice.close()
        if control is not None:
            control.stop()


def _listen(address: str | None, opts):
    """The robot's arm messages on ``address`` (the daemon's own control socket reader and parser), or None."""
    if not address:
        return None
    from firmware_io.recordings.arm_marks import ArmMarkLog
    from runtime.control import ControlSocket

    opts.arm_log = ArmMarkLog()
    control = ControlSocket(address, on_grasp=lambda closed, source: None, on_arm=opts.arm_log.note).start()
    print(f"listening on {address} for 'arm moving' / 'arm still'; the marks are stored with the recording", flush=True)
    return control


def idle_minutes(args: argparse.Namespace) -> float:
    """Minutes of idle this session records (``--idle-minutes``, else the default for the mode)."""
    if args.idle_minutes is not None:
        return float(args.idle_minutes)
    return IDLE_ONLY_MINUTES if args.idle_only else DEFAULT_IDLE_MINUTES


def _plan_and_options(args: argparse.Namespace):
    """The protocol to walk and how; raises SessionError for a bad pose, object or action list."""
    from firmware_io.recordings.record_session import ProtocolPlan, SessionOptions
    from firmware_io.recordings.terminal_view import trial_view

    plan = ProtocolPlan.from_text(args.poses, args.objects, args.actions, args.runs)
    from trainer.dataset import case_check, dataset_trigger

    opts = SessionOptions(trial_seconds=args.trial_seconds, lead_in_seconds=args.lead_in, gap_seconds=args.gap, countdown=args.countdown,
                          fraction=args.fraction or PAPER_FRACTION, pads=args.pads, auto=args.auto, retries=args.retries,
                          case_check=case_check(dataset_trigger(fraction=args.fraction), pads=args.pads),
                          max_trials=args.max_trials, quick_look=None if args.no_look else trial_view)
    return plan, opts


def _connect(device: str, trial_seconds: float):
    """A client for the device (reconnecting by URL) and, for ``subject://``, the simulated subject it
    reaches, whom the session prompts. Each scheme's URL is checked by its transport, in the one registry."""
    from firmware_io.client import DSAClient
    from firmware_io.transports import validate_url
    from firmware_io.transports.emulated import SUBJECT_SCHEME

    parsed = validate_url(device)
    if parsed.scheme != SUBJECT_SCHEME:
        return DSAClient(device, on_wait=lambda line: print(f"handover record: {line}", file=sys.stderr, flush=True)), None
    from firmware_io.sim.scripted_subject import ScriptedSubject

    subject = ScriptedSubject.from_url(parsed)
    subject.trial_seconds = max(trial_seconds, 1.5)
    return DSAClient(subject.connect), subject


def _record(args: argparse.Namespace, client, subject, plan, opts, voice: Voice) -> int:
    """Open the device and the session file, walk the protocol; the exit code."""
    from firmware_io.recordings.bounded_zip import first_line
    from firmware_io.recordings.idle_session import run_idle
    from firmware_io.recordings.idle_stretches import idle_plan
    from firmware_io.recordings.record_session import (
        DeviceLost,
        NotSaved,
        SessionIO,
        SessionStore,
        recording_path,
        run_session,
    )
    from firmware_io.transports.base import TransportError
    from firmware_io.wire.errors import DSAError

    try:
        layout = client.open()
        client.start()
    except (TransportError, DSAError, OSError) as exc:
        raise DeviceFailure(f"cannot open the device: {exc}") from None
    store = SessionStore.open(recording_path(args.out, args.subject), args.subject, layout)
    if problem := _resume_problem(store.meta.get("sessions", []), plan, opts, client.url, args.idle_only):
        raise HandoverError(f"{store.path}: {problem}")
    if subject is not None:
        store.meta.update(subject.meta)

    def show(text: str) -> None:
        if not (args.quiet and args.auto):  # a person at the hand needs the instructions; a script the result only
            print(text, flush=True)

    def say(text: str) -> None:
        show(text)
        voice.say(text)

    io = SessionIO(say=say, show=show, ask=_ask,
                   cue=subject.cue if subject is not None else (lambda kind, slot: None))
    info = {"device": client.url, "controller": _controller_info(client)}
    resume = "run the same command again to resume"
    idle_plan_ = idle_plan(idle_minutes(args))
    result = idle = None
    try:
        if not args.idle_only:
            result = run_session(client, store, plan, opts, io, session_info=info)
        if args.idle_only or (result.complete and idle_plan_):
            idle = run_idle(client, store, idle_plan_, opts, io, session_info=info)
    except NotSaved as exc:  # a full disk: what the file holds, and how to go on
        raise HandoverError(f"{exc}; {_saved(store)}; free disk space, then {resume}") from None
    except (DeviceLost, TransportError, DSAError) as exc:
        raise DeviceFailure(f"device lost ({first_line(exc)}); {_saved(store)}; {resume}") from None
    except ValueError as exc:  # a SessionError too
        raise HandoverError(str(exc)) from None
    except KeyboardInterrupt:
        raise Interrupted(f"interrupted; {_saved(store)}; {resume}") from None
    flagged = _flagged_text(result.flagged, store.path) if result else ""
    if result is not None and not result.complete:
        print(f"session stopped ({result.stopped}): {result.done} of {result.planned} trials done; "
              f"{_saved(store)}{flagged}; run the same command again to continue")
    elif idle is not None and not idle.complete:
        print(f"session stopped ({idle.stopped}): {idle.done} of {idle.planned} idle stretches done; "
              f"{_saved(store)}{flagged}; run the same command again to continue")
    else:
        print(f"session complete: {_saved(store)}{flagged}")
    return 0


PLAN_OPTIONS = (("poses", "--poses"), ("objects", "--objects"), ("actions", "--actions"), ("runs", "--runs"),
                ("trial_seconds", "--trial-seconds"), ("lead_in_seconds", "--lead-in"))
"""What a subject's trials are (the stored session's key, its option): a resumed session must keep them, or
its trials would mix two protocols (or two simulated people) under one subject id."""


def _resume_problem(sessions: list, plan, opts, device: str, idle_only: bool = False) -> str | None:
    """Why resuming a subject's file with these options would change its session (one line), else None.
    Idle stretches may be added with other idle options; a real device may move to another port."""
    stored = next((s for s in sessions if isinstance(s, dict) and isinstance(s.get("protocol"), dict)), None)
    given = {**plan.to_dict(), "trial_seconds": opts.trial_seconds, "lead_in_seconds": opts.lead_in_seconds}
    diffs = []
    if stored is not None and not idle_only:
        was = {**stored["protocol"], **{k: stored.get(k) for k in ("trial_seconds", "lead_in_seconds")}}
        for key, option in PLAN_OPTIONS:
            old, new = was.get(key), given[key]
            if old is None:
                continue
            if isinstance(new, list):
                same, old_text, new_text = list(old) == new, ",".join(map(str, old)), ",".join(new)
            else:
                same, old_text, new_text = math.isclose(float(old), float(new)), f"{old:g}", f"{new:g}"
            if not same:
                diffs.append((f"{option} {old_text}", f"{option} {new_text}"))
    old_person = next((_subject_person(s.get("device")) for s in sessions if isinstance(s, dict)
                       and _subject_person(s.get("device")) is not None), None)
    new_person = _subject_person(device)
    if old_person is not None and new_person is not None and old_person != new_person:
        diffs.append((f"subject://?{old_person}", new_person))
    if not diffs:
        return None
    return ("recorded with " + ", ".join(o for o, _ in diffs) + ", not " + ", ".join(n for _, n in diffs)
            + ": resume with the original options, or record under a new --subject id")


def _subject_person(url: object) -> str | None:
    """The simulated person of a ``subject://`` URL: ``seed=S`` (default 0), ``&lab=L`` unless lab A; None for
    any other device."""
    from urllib.parse import parse_qs, urlsplit

    from firmware_io.sim.lab import DEFAULT_LAB, UnknownLab, get_lab
    from firmware_io.transports.emulated import SUBJECT_SCHEME

    if not isinstance(url, str) or not url.startswith(f"{SUBJECT_SCHEME}://"):
        return None
    query = parse_qs(urlsplit(url).query)
    try:
        lab = get_lab(query.get("lab", [None])[0]).name
    except UnknownLab:  # a stored URL from elsewhere: compared as written
        lab = query["lab"][0]
    return f"seed={query.get('seed', ['0'])[0]}" + ("" if lab == DEFAULT_LAB else f"&lab={lab}")


def _flagged_text(flagged: list[int], path) -> str:
    """Which trials (1-based, as ``handover plot --trial`` counts them) training gets no case from, and how to
    look at one; "" when none."""
    if not flagged:
        return ""
    shown = ", ".join(str(i + 1) for i in flagged[:5]) + (" ..." if len(flagged) > 5 else "")
    one = len(flagged) == 1
    return (f", {len(flagged)} flagged (trial{'' if one else 's'} {shown}): training gets no case from "
            f"{'it' if one else 'them'}; look at {'it' if one else 'one'} with `handover plot {path} --trial {flagged[0] + 1}`")


def _saved(store) -> str:
    """What the file holds; before the first save there is no file to name as holding 0 trials."""
    if not store.path.exists():
        return f"nothing saved yet ({store.path} was not written)"
    idle = (f" and {store.n_idle} idle stretch{'' if store.n_idle == 1 else 'es'} ({store.idle_seconds() / 60:.1f} min)"
            if store.n_idle else "")
    return f"{store.n_trials} trial{'' if store.n_trials == 1 else 's'}{idle} saved in {store.path}"


def _controller_info(client) -> dict:
    c = getattr(client, "controller", None)
    if c is None:
        return {}
    sensor = getattr(client, "sensor", None)
    return {"serial_no": getattr(c, "serial_no", None), "sw_version": getattr(c, "sw_version", None),
            "sensor_serial_no": getattr(sensor, "serial_no", None)}
