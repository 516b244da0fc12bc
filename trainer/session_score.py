"""Scoring a captured event stream against a scripted session: the demo's summary, for any capture.

The rule itself (which report answers which scripted event, what counts as missed, wrong or
outside) is ``trainer.streams_eval.session_outcomes``; this module turns event lines into its
input (device time -> frame of the session, ``firmware_io.emulator.script_file``) and its
output into the summary the demo prints, so ``handover demo`` and ``handover score`` say the
same thing about the same session.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Iterator

from firmware_io.emulator.script_file import SessionScript
from firmware_io.recordings.bounded_zip import loads
from firmware_io.recordings.recording import Trial, name_problem
from trainer.streams_eval import Decision, session_outcomes

__all__ = ["capture_problem", "decisions_from_lines", "lines_of", "not_played_line", "outcome_summary",
           "score", "summary_lines"]

MAX_SCORED_EVENTS = 50_000
"""Scripted events one score covers (each pass between the first and last decision repeats the script's
events): over a day of a looping 180-trial session (29,000), as long as ``MAX_EVENT_LINES`` lasts; a garbled
stamp or a 1 ms loop would be billions."""
MAX_EVENT_LINES = 50_000
"""Lines one score reads: the daemon writes one per decision (and one per model swap), decisions 1.5 s apart
by default, so this is 21 hours of non-stop handovers (a bomb beyond it: ./dev bench hostile, case 15)."""
MAX_LINE_CHARS = 16 << 10
"""The longest line parsed: a decision line with the scores of 100 classes is under 4,000 characters; one
line of 10 million ``{}`` would take gigabytes."""


@dataclasses.dataclass
class Capture:
    """What ``decisions_from_lines`` found in the EVENTS file."""

    decisions: list[tuple[int, Decision]]
    skipped: int
    """Lines that are not JSON objects, and decision lines that cannot be read."""
    given: int
    """Lines that are not blank."""
    scripted: int = 0
    """Lines of a script (``handover emulate --script-out``'s), given as the events."""


def lines_of(text: str) -> Iterator[str]:
    """The lines of ``text`` one at a time (``splitlines`` would hold a second copy of 128 MiB)."""
    start = 0
    while start < len(text):
        end = text.find("\n", start)
        end = len(text) if end < 0 else end
        yield text[start:end]
        start = end + 1


def decisions_from_lines(lines: Iterable[str], script: SessionScript, instance: str | None = None) -> Capture:
    """Decision lines as (pass, Decision), in order; stops after ``MAX_EVENT_LINES`` + 1 lines. Lines of other
    types are skipped as the protocol says; ``instance``: only that daemon's."""
    c = Capture([], 0, 0)
    for line in lines:
        blank = not line.strip()
        c.given += not blank
        if c.given > MAX_EVENT_LINES:
            break
        try:
            if len(line) > MAX_LINE_CHARS:
                raise ValueError("longer than any event line")
            obj = loads(line)
        except ValueError:
            c.skipped += not blank
            continue
        if not isinstance(obj, dict) or obj.get("type") != "decision":
            c.skipped += not isinstance(obj, dict)
            c.scripted += isinstance(obj, dict) and obj.get("type") in ("script", "scripted")
            continue
        if instance is not None and obj.get("instance") != instance:
            continue
        try:
            if name_problem("class", obj.get("class")):  # echoed in the summary
                raise ValueError("not a class name")
            loop, frame = script.frame_of(int(obj["device_time_ms"]))
            c.decisions.append((loop, Decision(frame, obj["class"], float(obj.get("latency_us", 0.0)))))
        except (KeyError, TypeError, ValueError, OverflowError):  # OverflowError: a time of 1e400
            c.skipped += 1
    return c


def capture_problem(c: Capture, script: SessionScript) -> str | None:
    """Why the EVENTS file cannot be scored against ``script`` (one line), or None."""
    if c.given > MAX_EVENT_LINES:
        return (f"more than {MAX_EVENT_LINES} lines (21 hours of non-stop handovers); score a part of the capture "
                "(e.g. the lines of one session)")
    if c.scripted and not c.decisions:
        return ("a script (what handover emulate --script-out writes), not event lines; give the daemon's event "
                "lines first, then the script")
    if c.skipped == c.given:  # e.g. the daemon's log, not its stdout
        return (f"none of its {c.given} lines is an event line (a JSON object); give the daemon's event lines "
                "(its stdout or a UDP listener's), not its log")
    return _span_problem(c.decisions, script)


def _span_problem(decisions: list[tuple[int, Decision]], script: SessionScript) -> str | None:
    """Why ``score`` would expand too many scripted events (passes x events), or None."""
    passes = {loop for loop, _ in decisions}
    n = (max(passes) - min(passes) + 1) if passes else 1
    if n * len(script.trials) <= MAX_SCORED_EVENTS:
        return None
    return (f"its decisions span {n} passes of the script's {len(script.trials)} events (at most {MAX_SCORED_EVENTS} "
            "scripted events are scored); a line's device_time_ms is garbled, or the events are not from this session")


def score(decisions: list[tuple[int, Decision]], script: SessionScript) -> dict:
    """``session_outcomes`` over the passes the decisions fall in (a looping session repeats its
    script; passes before the first and after the last decision were not watched). Unless the
    script says the session was sent whole, events that start after the last decision are
    ``not_played`` (the capture ended while the session was still playing), not missed."""
    passes = sorted({loop for loop, _ in decisions}) or [0]
    n = len(script.frame_ms)
    first, last = passes[0], passes[-1]
    trials = [Trial(t.subject, t.object, t.pose, t.action, t.run, t.first + p * n, t.last + p * n,
                    {**t.extra, "onset": int(t.extra.get("onset", t.first)) + p * n})
              for p in range(first, last + 1) for t in script.trials]
    flat = [Decision(d.frame + loop * n, d.cls, d.latency_us) for loop, d in decisions]
    end = max((d.frame for d in flat), default=None)
    played = trials if end is None or script.ended else [t for t in trials if t.first <= end]
    outcomes = session_outcomes(flat, played)
    outcomes["passes"] = last - first + 1
    outcomes["not_played"] = len(trials) - len(played)
    outcomes["capture_end"] = None if end is None else {"pass": end // n, "frame": end % n,
                                                         "last_event_frame": int(trials[-1].extra["onset"]) % n}
    return outcomes


def not_played_line(o: dict, events: str) -> str | None:
    """One line when the capture ended before the script did (``score``'s ``not_played``)."""
    if not o.get("not_played"):
        return None
    end = o["capture_end"]
    where = f"frame {end['frame']}" + (f" of pass {end['pass'] + 1}" if o["passes"] > 1 else "")
    return (f"{events} ends at {where} (its last decision), before the script's last event at frame "
            f"{end['last_event_frame']}: {o['not_played']} scripted events after it are counted as not played yet, "
            "not missed (the session was still playing; score again once it is over)")


def outcome_summary(o: dict) -> dict:
    """``session_outcomes``' result under the names the demo's summary (and its --json) uses."""
    return {
        "events_expected": o["expected"],
        "events_detected": o["detected"],
        "events_correct": o["correct"],
        "events_missed": o["missed"],
        "events_not_played": o.get("not_played", 0),
        "false_events": o["outside"],
        "repeat_events": o["repeats"],
        "missed_events": o["missed_events"],
        "wrong_events": o["wrong_events"],
        "per_class_precision": {c: v["precision"] for c, v in o["per_class"].items()},
        "per_class_recall": {c: v["recall"] for c, v in o["per_class"].items()},
        "per_class_correct": {c: f"{v['correct']}/{v['n']}" for c, v in o["per_class"].items() if v["n"]},
        "report_minus_onset_frames": o["report_minus_onset_frames"],
        "report_minus_onset_frames_per_class": o.get("report_minus_onset_frames_per_class"),
    }


def summary_lines(s: dict, setting: str | None = None) -> list[str]:
    """The summary's event lines: right, wrong, missed, outside, onset to report."""
    lines = [
        f"  events: {s['events_expected']} scripted, {s['events_detected']} detected, "
        f"{s['events_correct']} correct ({s['events_correct'] / max(1, s['events_expected']):.0%}), "
        f"{s['events_missed']} missed, {s['false_events']} outside any scripted event",
        "  per class correct: " + (_listed([f"{c} {v}" for c, v in s["per_class_correct"].items()]) or "-"),
        "  per class precision / recall: " + _listed(
            [f"{c} {_share(p)} / {_share(s['per_class_recall'][c])}" for c, p in s["per_class_precision"].items()]),
        "  missed: " + (_listed([f"#{e['event']} {e['action']} (onset frame {e['onset']})"
                                 for e in s["missed_events"]]) or "none"),
        "  wrong: " + (_listed([f"#{e['event']} {e['action']} reported as {e['reported']} at frame {e['frame']} "
                                f"(onset {e['onset']})" for e in s["wrong_events"]]) or "none"),
    ]
    if s["report_minus_onset_frames"]:
        where = f" (stream setting: {setting})" if setting else ""
        d = s["report_minus_onset_frames"]
        per = s.get("report_minus_onset_frames_per_class") or {}
        lines.append(f"  onset to report: median {d['median']:.0f} frames, p90 {d['p90']:.0f}{where}"
                     + ("; per class median / p90: " + ", ".join(f"{c} {v['median']:.0f} / {v['p90']:.0f}"
                                                                for c, v in per.items() if v) if per else ""))
    return lines


def _share(x: float | None) -> str:
    return "-" if x is None else f"{x:.0%}"


SHOWN = 20
"""Items one summary line lists: a line for people; --json lists them all (100,000 missed events were 2.8 MB)."""


def _listed(items: list[str]) -> str:
    more = f", ... and {len(items) - SHOWN} more (--json lists all)" if len(items) > SHOWN else ""
    return ", ".join(items[:SHOWN]) + more
