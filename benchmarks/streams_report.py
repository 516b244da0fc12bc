"""results/streams.md from the result of ``./dev bench streams`` (benchmarks/streams.py)."""

from __future__ import annotations

from runtime.trigger_settings import window_start_text
from trainer import streams_eval as se

MODE_TEXT = {
    "threshold": "threshold 15 % (the paper) + 4-class model",
    "baseline": "threshold above a tracked per-taxel baseline + 4-class model",
    "onset": "onset trigger (per-pad change against the settled grasp) + 4-class model",
    "onset_robot": "onset trigger + the robot's `grasp closed` / `grasp open` + 4-class model",
    "onset_dormant": "onset trigger + 5-class model (a window read as dormant is not reported)",
    "continuous": "continuous, 5-class model with dormant class and level features + report rule",
    "onset_arm": "onset + 4-class model + the robot's `arm moving` / `arm still`",
    "onset_dormant_arm": "onset + 5-class model + the robot's `arm moving` / `arm still`",
    "continuous_arm": "continuous + the robot's `arm moving` / `arm still`",
}


def _f(x, spec: str = ".2f") -> str:
    return "-" if x is None else format(x, spec)


def _pct(x) -> str:
    return "-" if x is None else f"{100 * x:.0f} %"


def _counts(r: dict) -> str:
    """Continuous mode's holds right of held, and the recall's exact 95 % interval (older files have neither)."""
    counts, ci = r.get("continuous_hold_counts"), r.get("continuous_hold_recall_95")
    if not counts or not ci:
        return ""
    return f"{counts[0]} of {counts[1]}, 95 % interval {100 * ci[0]:.0f}-{_pct(ci[1])}; "


def markdown(r: dict, load_text: str) -> list[str]:
    chosen = r["default_setting"]
    lines = [
        "# Events in a live stream (real idle recordings; synthetic event streams)",
        "",
        "Every stream is replayed frame by frame through the real daemon (`Daemon.serve` + `handle_frame`: ring, "
        "trigger, ONNX model, report rule; `trainer/streams_eval.py`). Event streams come from the simulated hand "
        "(**synthetic**); the real SDH-2 recordings hold no handover and measure false events only.",
        "",
        "## Headline",
        "",
        f"- default stream setting (chosen on validation streams, rule below): **{chosen}**",
    ]
    real = r.get("real")
    if real:
        lines.append(f"- real SDH-2 recordings without a handover: {real['files']} files, {real['hours']:.2f} h: "
                     f"**{_f(r['real_idle_false_events_per_hour'])} false events per hour** with the default setting "
                     f"({real['events'][chosen]} events); by mode: "
                     + ", ".join(f"{m} {_f(v)}/h" for m, v in real["false_per_hour"].items())
                     + f"; without the ~70 Hz frequency-analysis files ({real['hours_at_model_rate']:.2f} h): "
                     + ", ".join(f"{m} {_f(v)}/h" for m, v in real["false_per_hour_at_model_rate"].items())
                     + f"; on the real test half alone (files not used to choose, {real['split']['test']['hours']:.2f} h): "
                     f"{_f(r['real_test_half_false_events_per_hour'])}/h with the default setting")
    else:
        lines.append("- real recordings: not found (set HANDOVER_SHARED_DATA), no real figure")
    d = r["demo"][chosen]
    lines += [
        f"- the demo's scripted session ({d['expected']} events, unseen simulated subjects, synthetic): "
        f"**{d['correct']}/{d['expected']} right ({_pct(d['correct_fraction'])})**, {d['missed']} missed, "
        f"{d['outside']} outside any scripted event, {d['repeats']} repeats",
        "- test streams (synthetic, unseen subjects and hand): event F1 (macro over classes) "
        + ", ".join(f"{m} {_f(v)}" for m, v in r["sim_event_f1"].items()),
        f"- continuous mode: {_pct(r['continuous_events_correct_fraction'])} of events right, hold recall "
        f"{_pct(r['continuous_hold_recall'])} ({_counts(r)}report rule {_rule(r.get('continuous_rule'))}, chosen on "
        "validation streams below)",
        "- median onset-to-report (frames; T = 15): "
        + ", ".join(f"{m} {_f(v, '.0f')}" for m, v in r["onset_to_report_median_frames"].items()),
        "",
    ]
    lines += _test_table(r) + _delay_per_class(r) + _arm(r) + _per_class(r) + _choice(r) + _rule_choice(r) + _demo(r) + _real(r)
    trig = r.get("onset_trigger") or {}
    lines += ["", "## Notes", "", load_text,
              f"Onset trigger settings (runtime/config_keys.py; how they were chosen: docs/TRIGGER_DEFAULTS.md): change "
              f"{trig.get('change')}, floor {trig.get('floor')} x full scale, baseline tau {trig.get('track_tau_s')} s, "
              f"settle {trig.get('settle_s')} s (or 3 x that at twice the change on a noisy hand: `NOISY_SETTLE`), "
              f"{window_start_text({'kind': 'onset', **trig})}.",
              "Product rules the false events on real files led to: the daemon feeds a model at its "
              "trained period (runtime/frame_rate.py: a faster stream is decimated, a slower one gets a health line; "
              "a gap of more than 10 stream periods restarts the stream's history like a reconnect); the onset "
              "trigger fires only on a pad rising by the change (a departure in which no pad rose that much is the "
              "hand letting go; `RELEASE_RISE`, chosen by the rule above over 0.25 / 0.5 / 1.0: utility 37 / 39 / 40, "
              "the same 53 right events each, fewer false events in the idle stream and on the real validation "
              "files, a cup and a pen the hand let go) on a contact of at least 3 loaded taxels "
              "(`MIN_CONTACT_TAXELS`, physical grounds: the simulated grasps load 6 taxels or more at every fire, "
              "no fire on the real validation files is on fewer than 4; the rule was indifferent; set after a real "
              "slip test on a 2-taxel contact), and only "
              "while the settled grasp touches pads of at least 2 fingers (`MIN_GRASP_FINGERS`: a hand-over starts "
              "from an object held between opposing fingers; a rig or probe pressing one finger holds nothing; "
              "chosen by the rule above over 1 (off) / 2: utility 40 / 43, the same synthetic reports, real "
              "validation false events 4 / 1; 3 was not a candidate: the hand holds objects between two fingers, "
              "the xmas ball among them). Left alone: the xmas ball's false event (the hand's own grip tightening "
              "on two fingers, every pad up by the same share, no contact moving) looks like a pull that wedges the "
              "object before it slips; no trigger rule told them apart without risking pulls.",
              f"Sizes: {r['sizes']}; training seed {r['seed']}, validation seed {r['seed'] + 2}, test seed "
              f"{r['seed'] + 1}. The simulator's frames were not changed for this benchmark (its streams carry the marks of its own arm moves). {r['seconds']:.0f} s."]
    return lines


def _sizes(info: dict) -> str:
    return (f"{info['seed']}: {info['events']} scripted events in {info['mixed_hours']:.2f} h of mixed stream (idle "
            f"holds between them) + {info['idle_hours']:.2f} h of idle stream, synthetic")


def _test_table(r: dict) -> list[str]:
    t = r["test"]
    info = t["_info"]
    lines = ["## Test streams (synthetic, run once)", "",
             f"Seed {_sizes(info)}; unseen subjects and another hand; the idle stream holds creep, drift, arm moves, "
             "regrasps, grasp and release, open hand. A scripted event owns the frames from 2 before its onset to "
             "its end; its first report there is its answer, later ones are duplicates; reports outside are false.", "",
             "| mode | right / n | F1 (macro) | missed | wrong | duplicates | onset-to-report median / p90 (frames) | "
             "false / h (idle stream) | false / h (mixed, idle part) |", "|---|---|---|---|---|---|---|---|---|"]
    for m in se.MODES:
        x = t[m]["mixed"]
        d = x["delay_frames"] or {}
        lines.append(f"| {MODE_TEXT[m]} | {x['correct']}/{x['n_events']} | {_f(t[m]['f1'])} | {x['missed']} | "
                     f"{x['wrong_class']} | {x['duplicates']} | {_f(d.get('median'), '.0f')} / {_f(d.get('p90'), '.0f')} | "
                     f"{_f(t[m]['idle']['false_per_hour'], '.1f')} | {_f(x['false_per_hour'], '.1f')} |")
    lines += ["", "False events in the idle stream by what was going on:", "",
              "| mode | " + " | ".join(f"{k}" for k in ("quiet", "arm_move", "regrasp", "grasp", "release", "open"))
              + " |", "|---|---|---|---|---|---|---|"]
    for m in se.MODES:
        src = t[m]["idle"]["false_by_source"]
        lines.append(f"| {m} | " + " | ".join(str(src.get(k, 0)) for k in
                                               ("quiet", "arm_move", "regrasp", "grasp", "release", "open")) + " |")
    return [*lines, ""]


def _delay_per_class(r: dict) -> list[str]:
    """Onset-to-report frames per true action, median / p90, on the test mixed stream (early heads answer
    some classes sooner than others: docs/EARLY.md)."""
    t = r["test"]
    classes = sorted({c for m in se.MODES for c in (t[m]["mixed"].get("delay_frames_per_class") or {})})
    if not classes:
        return []
    lines = ["Onset-to-report frames per class, median / p90 (test mixed stream, synthetic):", "",
             "| mode | " + " | ".join(classes) + " |", "|---|" + "---|" * len(classes)]
    for m in se.MODES:
        per = t[m]["mixed"].get("delay_frames_per_class") or {}
        lines.append(f"| {m} | " + " | ".join(
            f"{_f((per.get(c) or {}).get('median'), '.0f')} / {_f((per.get(c) or {}).get('p90'), '.0f')}"
            for c in classes) + " |")
    return [*lines, ""]


def _arm(r: dict) -> list[str]:
    """False events while the arm moves, with and without the robot saying so."""
    t = r["test"]
    hours = t["_info"]["idle_source_hours"].get("arm_move")
    from runtime.config_keys import key

    settle_s = key("control.arm_settle_s").default

    lines = ["## The robot says when its arm moves (test idle stream, synthetic)", "",
             f"The simulated robot sends `arm moving` when a move starts and `arm still` when it ends (the simulator's "
             f"own plan, `firmware_io.sim.idle.move_marks`); the daemon judges every window that holds a frame from "
             f"`arm moving` to {settle_s:g} s after `arm still` as dormant (runtime/arm_motion.py). Arm-move time in "
             f"the idle stream: {_f(hours, '.3f')} h (the move plus 0.5 s of settling, the simulator's `arm_move` "
             "source); a false event counts for the source of the frame that ended its window.", "",
             "| model and trigger | without the robot's arm messages: false during arm moves (per hour of arm "
             "move) / all false per hour of idle | with them |", "|---|---|---|"]
    for base, text in (("onset", "onset trigger + 4-class model"), ("onset_dormant", "onset trigger + 5-class model"),
                       ("continuous", "continuous, 5-class model")):
        cells = []
        for m in (base, f"{base}_arm"):
            idle = t[m]["idle"]
            cells.append(f"{idle['false_by_source'].get('arm_move', 0)} ({_f(idle.get('arm_move_false_per_hour'), '.1f')}"
                         f"/h) / {_f(idle['false_per_hour'], '.1f')}/h")
        lines.append(f"| {text} | {cells[0]} | {cells[1]} |")
    return [*lines, ""]


def _per_class(r: dict) -> list[str]:
    t = r["test"]
    classes = sorted({c for m in se.MODES for c in t[m]["mixed"]["per_class"]})
    lines = ["## Per class (test mixed stream): precision / recall", "",
             "Precision: right first reports of the class / all reports of it (duplicates and false events "
             "included); recall: of the scripted events of the class.", "",
             "| mode | " + " | ".join(classes) + " |", "|---|" + "---|" * len(classes)]
    for m in se.MODES:
        pc = t[m]["mixed"]["per_class"]
        lines.append(f"| {m} | " + " | ".join(
            f"{_f(pc[c]['precision'])} / {_f(pc[c]['recall'])}" if c in pc else "-" for c in classes) + " |")
    return [*lines, ""]


def _choice(r: dict) -> list[str]:
    v = r["validation"]
    info = v["_info"]
    lines = ["## How the default was chosen", "",
             f"On validation streams of their own seed ({_sizes(info)}), before the test streams were generated, among "
             f"the settings the daemon runs without the robot ({', '.join(r['candidates'])}); criterion: "
             f"{r['criterion']}. `onset_robot` is listed for comparison (the robot's messages are optional).",
             "", "| mode | right | wrong | missed | duplicates | false events (synthetic) | false events (real "
             "validation files) | utility | median onset-to-report |", "|---|---|---|---|---|---|---|---|---|"]
    for m in se.MODES:
        x = v[m]["mixed"]
        false = x["false_events"] + v[m]["idle"]["false_events"]
        d = x["delay_frames"] or {}
        lines.append(f"| {m}{' (chosen)' if m == r['default_setting'] else ''} | {x['correct']} | {x['wrong_class']} | "
                     f"{x['missed']} | {x['duplicates']} | {false} | {v[m].get('real_validation_false_events', '-')} | "
                     f"{v[m].get('utility_with_real', v[m]['utility'])} | {_f(d.get('median'), '.0f')} |")
    if r.get("real"):
        sp = r["real"]["split"]
        lines += ["", f"Real validation recordings: {sp['validation']['files']} files, {sp['validation']['hours']:.2f} h; "
                  f"real test recordings: {sp['test']['files']} files, {sp['test']['hours']:.2f} h, false events per "
                  "hour there: " + ", ".join(f"{m} {_f(x)}" for m, x in sp["test"]["false_per_hour"].items()) + "."]
    return [*lines, ""]


def _rule(rule: dict | None) -> str:
    return "-" if not rule else ", ".join(f"{k} {v}" for k, v in rule.items())


def _rule_choice(r: dict) -> list[str]:
    c = r.get("continuous_rule_choice")
    if not c:
        return []
    st = c["streams"]
    same = c["chosen"] == c["shipped"]
    lines = ["## Continuous mode's report rule: how it was chosen", "",
             f"Chosen: {_rule(c['chosen'])} (runtime/decision.py; `[continuous]` in runtime/config_keys.py ships "
             f"{'the same' if same else _rule(c['shipped']) + ': NOT the chosen rule'}). On validation streams (seed "
             f"{st['seed']}: {st['events']} scripted events in {st['mixed_hours']:.2f} h of mixed stream + "
             f"{st['idle_hours']:.2f} h of idle stream, synthetic), before the test streams were generated, over "
             f"the grid {c['grid']}; criterion: {c['criterion']}. The continuous rows of every table above use it. "
             "The ten best rules, then the shipped and the previous rule (8, 0, 4) where not among them:", "",
             "| confirm | margin | rearm | gap | vote | right | wrong | missed | duplicates | false events | hold recall "
             "| median onset-to-report | utility |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    rows = list(c["best"])
    for extra in (c.get("shipped_row"), c.get("previous_row")):
        if extra and extra not in rows:
            rows.append(extra)
    for x in rows:
        lines.append(f"| {x['confirm_frames']} | {x['min_margin']:g} | {x['rearm_frames']} | {x['gap_frames']} | "
                     f"{x['vote']} | {x['correct']} | {x['wrong']} | {x['missed']} | {x['duplicates']} | "
                     f"{x['false_events']} | {_pct(x['hold_recall'])} | {_f(x['delay_median_frames'], '.1f')} | "
                     f"{x['utility']} |")
    return [*lines, ""]


def _demo(r: dict) -> list[str]:
    demo = r["demo"]
    lines = ["## The demo's scripted session (synthetic)", "",
             f"`handover demo`'s session (seed {demo['seed']}, 40 events by unseen simulated subjects), in-process "
             "through the daemon; a report inside an event's span (object placed .. taken away) answers it.", "",
             "| mode | right | missed | wrong | outside any event | repeats | report - onset median (frames) |",
             "|---|---|---|---|---|---|---|"]
    for m, d in demo.items():
        if not isinstance(d, dict):
            continue
        st = d["report_minus_onset_frames"] or {}
        lines.append(f"| {m} | {d['correct']}/{d['expected']} | {d['missed']} | {len(d['wrong_events'])} | "
                     f"{d['outside']} | {d['repeats']} | {_f(st.get('median'), '.0f')} |")
    d = demo[demo["mode"]]
    if d["missed_events"] or d["wrong_events"]:
        lines += ["", f"Default setting ({demo['mode']}): missed "
                  + (", ".join(f"#{e['event']} {e['action']}" for e in d["missed_events"]) or "none")
                  + "; wrong " + (", ".join(f"#{e['event']} {e['action']} read as {e['reported']}"
                                            for e in d["wrong_events"]) or "none") + "."]
    return [*lines, ""]


def _real(r: dict) -> list[str]:
    real = r.get("real")
    if not real:
        return []
    modes = list(real["false_per_hour"])
    lines = ["## Real SDH-2 recordings without a handover", "",
             f"Every recording under `{real['root']}` ({real['files']} files, {real['hours']:.2f} h of recording time; "
             "time = last minus first time stamp, so the 3 s-per-frame temperature-noise file counts its 65 min). "
             "None holds a human handover (the data's README: none is labelled with handover events; they are "
             "calibration, grasping, object and slip experiments), so every reported event is a false event. "
             "In the slip sessions an object slides in or is drawn through the grasp, which is the closest to a "
             "pull these files hold.", "",
             "| category | files | hours | why it counts as idle | " + " | ".join(modes) + " |",
             "|---|---|---|---|" + "---|" * len(modes)]
    why = {row["category"]: row.get("why_idle", "") for row in real["rows"]}
    for cat, c in sorted(real["by_category"].items()):
        lines.append(f"| {cat} | {c['files']} | {c['hours']:.2f} | {why.get(cat, '')} | "
                     + " | ".join(str(c[m]) for m in modes) + " |")
    chosen = r["default_setting"]
    left = [row for row in real["rows"] if row.get("events", {}).get(chosen)]
    lines += ["", f"False events left with the default setting ({chosen}), per file (split: which half of the "
              "sorted files it is in; validation files take part in choosing settings):", ""]
    lines += [f"- `{row['file']}` ({row['category']}, {row['split']}): {len(row['events'][chosen])} "
              f"{row['events'][chosen]}" for row in left] or ["- none"]
    lines += ["", "Files with events (events per mode):", ""]
    for row in real["rows"]:
        if "events" in row and any(row["events"].values()):
            lines.append(f"- `{row['file']}` ({row['hours'] * 60:.1f} min): "
                         + ", ".join(f"{m} {len(v)} {v[:6]}" for m, v in row["events"].items() if v))
    skipped = [row for row in real["rows"] if "skipped" in row]
    for row in skipped:
        lines.append(f"- skipped `{row['file']}`: {row['skipped']}")
    return [*lines, ""]
