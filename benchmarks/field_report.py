"""results/field.md from ``./dev bench field``'s figures (benchmarks/field.py)."""

from __future__ import annotations

__all__ = ["markdown"]


def _score(name: str, s: dict) -> str:
    return (f"| {name} | {s['right']}/{s['events']} | {s['wrong']} | {s['missed']} | {s['false_events']} |")


def _shadow(h: dict | None, only: dict) -> str:
    if not h:
        return "no shadow figures in the health view (the daemon had no `[model] shadow`)"
    judged = (f"; judged by the robot's outcomes on {h['events_with_outcome']} events: serving right on "
              f"{h.get('serving_right')}, the candidate on {h.get('candidate_right')}") if "events_with_outcome" in h else ""
    return (f"agreement {h.get('agreement')} on {h.get('windows_compared')} windows; the candidate's events on "
            f"windows the serving model called dormant: {h.get('false_events_on_serving_dormant')} (by the script: "
            f"{only['right']} of {only['events']} right, the serving model's misses){judged}; the verdict: "
            f"\"{h.get('verdict')}\"")


def _capture(c: dict) -> list[str]:
    return [f"- events decided (event lines) {c['events_decided']}, events captured {c['events_captured']}; "
            f"windows decided but not reported (kept for review) {c['unreported_windows_captured']}; idle stretches "
            f"{c['idle_stretches_captured']}",
            f"- {c['bytes']:,} bytes for {c['stream_hours'] * 60:.1f} min of stream: **{c['bytes_per_hour']:,} bytes per "
            f"hour** at {c['events_per_hour']} events per hour; an event file {c['bytes_per_event_file']:,} bytes, "
            f"an idle file {c['bytes_per_idle_file'] or 0:,} bytes (a lab's day: events per hour x the first + idle "
            "stretches per hour x the second)"]


def _idle(idle: dict | None) -> str:
    if not idle:
        return "C has no dormant class (no idle read)."
    return (f"Its dormant class: {idle['dormant_windows']} windows ({idle['per_origin']}) from {idle['seconds'] / 60:.1f} "
            "min of idle, the lab's and the day's captured stretches; the emulated day's idle is a still held object "
            f"(source quiet), where the onset trigger rarely fires: the quiet source gave "
            f"{idle['per_origin'].get('trigger:quiet', 0)} of the trigger cut's windows, lab and field together.")


def markdown(r: dict) -> list[str]:
    d1, d2, sv = r["day1"], r["day2"], r["shadow_vs_promoted"]
    s = r["sizes"]
    lines = [
        "# Learning from the field, end to end (synthetic)", "",
        "A day compressed into minutes on the emulator: the serving model, a candidate in shadow, capture on, "
        "the robot's outcomes from a script that knows the truth; then `handover review --accept-outcomes`, "
        "`handover train --data lab/ --data field/`, the new model in shadow on another day, promoted by a file "
        "move, and that day played again. **All data are synthetic** (simulated hand and subjects); every step is "
        "the product's command in its own process (benchmarks/field.py, benchmarks/field_run.py).", "",
        f"Reproduce: `{r['command']}`. Machine: {r['machine'].get('cpu')}, load {r['load_before']} before, "
        f"{r['load_after']} after; {r['seconds']:.0f} s. Sessions at speed {s['speed']:g}; models trained with "
        "`--early off`.", "",
        f"## Day 1: {d1['serving_A']['events']} scripted events, A serving, B (no dormant class) in shadow", "",
        "| model | right | wrong | missed | false events |", "|---|---|---|---|---|",
        _score("A, serving", d1["serving_A"]), _score("B, in shadow (its reports)", d1["shadow_B"]), "",
        f"Shadow in the health view: {_shadow(d1['shadow_health'], d1['shadow_only_events'])}.", "",
        "Capture:", *_capture(d1["capture"]), "",
        f"The robot said {d1['outcomes_said']}. Review: {r['review']['line']} "
        f"({r['review']['labels_per_class']}). The robot says nothing about a window the daemon decided dormant "
        "(a missed event is one): those wait for a person in `handover review`.", "",
        f"## C: `handover train --data lab/ --data field/` ({r['trained_C']['n_trials']} trials, leave-one-subject-"
        f"out {r['trained_C']['loso_accuracy']:.3f}; the field's events are one subject)", "",
        _idle(r["trained_C"].get("idle")), "",
        "An event only the candidate reported is a false event to the shadow rule unless an outcome says otherwise: "
        "the robot says outcomes only about the serving model's events, so a candidate's right answer where the "
        "serving model missed stays counted against it (the script's count above says how many were right).", "",
        f"## Day 2: {d2['serving_A']['events']} scripted events, other simulated subjects", "",
        "| model | right | wrong | missed | false events |", "|---|---|---|---|---|",
        _score("A, serving", d2["serving_A"]), _score("C, in shadow (its reports on A's windows)", d2["shadow_C"]),
        _score("C, promoted (serving, the same session again)", d2["promoted_C"]), "",
        f"Shadow in the health view: {_shadow(d2['shadow_health'], d2['shadow_only_events'])}.", "",
        f"C promoted against A on day 2: {d2['promoted_C']['right']} against {d2['serving_A']['right']} right, "
        f"{d2['promoted_C']['false_events']} against {d2['serving_A']['false_events']} false events. The simulated "
        "sessions leave A little to learn: this run shows the loop working end to end, not what a day of field "
        "data is worth to a model.", "",
        f"**What shadow predicted against what the promoted model did**: on {sv['same_first_report']} of "
        f"{sv['events']} scripted events ({sv['share']}) C's first report in shadow was the class it reported once "
        f"serving (or neither reported); false events {sv['false_events_shadow']} in shadow against "
        f"{sv['false_events_promoted']} serving. In shadow C decides on the windows A's trigger cut; serving, on "
        "its own.", "",
        "Capture on day 2:", *_capture(d2["capture"]), "",
        "Frames (health view): " + "; ".join(f"{k} {v['frames_received']} received, {v['frames_dropped']} dropped, "
                                             f"{v['frames_stale']} stale" for k, v in r["frames_lost"].items())
        + ". The sessions are sent at a multiple of the device's rate on a shared 2-core machine; dropped or "
        "stale frames change a run's decisions.", "",
    ]
    return lines
