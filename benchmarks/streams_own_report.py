"""results/streams_own.md from the streams_own bench's result (benchmarks/streams_own.py)."""

from __future__ import annotations


def _rate(x) -> str:
    return "-" if x is None else f"{x:.1f}"


def _pct(x) -> str:
    return "-" if x is None else f"{100 * x:.0f} %"


def _early(rule: dict | None) -> str:
    if not rule:
        return "(none: the full window only)"
    if rule["threshold"] > 1:
        return "never reports early (threshold above every confidence)"
    return (f"reports at {', '.join(map(str, rule['points']))} frames when the calibrated confidence reaches "
            f"{rule['threshold']:g}{' and agrees with the previous head' if rule['agree'] else ''}")


def markdown(r: dict) -> list[str]:
    real, test, demo, rep = r["real"], r["test"], r["demo"], r.get("held_out_replay") or {}
    m = r["model"]
    lines = [
        "# A lab's own model on live streams (`./dev bench streams_own`)",
        "",
        f"Three scripted simulated subjects ({', '.join(r['subjects'])}; **synthetic**) recorded with `handover "
        f"record` (every pose, object and action, {r['sizes']['runs']} run(s), plus the recorder's idle stretches), "
        f"then `handover train` on the recordings: classes {', '.join(m['classes'])}, features "
        f"{'+'.join(m['families'] or [])}, {m['n_trials']} trials"
        + (f" + {m['idle']['dormant_windows']} dormant windows from {m['idle']['seconds'] / 60:.1f} min of idle"
           if m.get("idle") else "") + ".",
        "",
        "## Headline",
        "",
    ]
    if real:
        lines.append(f"- **real SDH-2 recordings without a handover** ({real['hours']:.2f} h, ../shared/data): "
                     f"{real['events']} false events, **{_rate(real['false_per_hour'])} per hour** ({real['mode']})")
    else:
        lines.append("- real SDH-2 recordings: not present on this machine (../shared/data), not measured")
    lines += [
        f"- synthetic idle test stream of `./dev bench streams` ({test['idle']['idle_hours']:.2f} h, seed "
        f"{r['seed'] + 1}): **{_rate(r['own_model_idle_false_events_per_hour'])} false events per hour** "
        f"(the demo's simulator-trained model: {_rate(r['demo_model_idle_false_events_per_hour'])}); with the robot's "
        f"`arm moving` / `arm still`: {_rate(r['own_model_idle_false_events_per_hour_arm_messages'])} per hour"
        + (f"; during the stream's arm moves ({test['idle']['arm_move_hours']:.2f} h): "
           f"{_rate(r['own_model_arm_move_false_events_per_hour'])} per hour without the robot's messages, "
           f"**{_rate(r['own_model_arm_move_false_events_per_hour_arm_messages'])} per hour with them**"
           if r.get("own_model_arm_move_false_events_per_hour_arm_messages") is not None else "")
        + (f"; answering only at the full window (`[scene] early_events = []`, no early heads' reports): "
           f"{_rate(r['own_model_idle_false_events_per_hour_full_window'])} per hour"
           if r.get("own_model_idle_false_events_per_hour_full_window") is not None else ""),
        f"- the demo's scripted session (40 events, unseen subjects, synthetic): {demo['correct']} of "
        f"{demo['expected']} right ({_pct(demo['correct_fraction'])}), {demo['missed']} missed, {demo['outside']} "
        "outside any event",
        f"- synthetic mixed test stream: {test['mixed']['correct']} of {test['mixed']['n_events']} right, "
        f"{test['mixed']['wrong_class']} wrong, {test['mixed']['missed']} missed, {test['mixed']['false_events']} false",
        "",
        f"Early reports: the model's rule {_early(m.get('early_rule'))}, chosen by `handover train` as "
        f"{r.get('early_rule_criterion') or '-'}.",
        "",
        "## Held-out replay in `handover train` (each subject replayed through the daemon, model trained without it)",
        "",
    ]
    if rep.get("folds"):
        from trainer.own_replay import replay_lines

        lines += [f"- {line}" for line in replay_lines(rep)]
    else:
        lines.append("- not measured")
    lines += [
        "",
        "## How dormant windows are cut (chosen on validation streams)",
        "",
        f"Rule: {r['criterion']}.",
        "",
        "| cut | lab | mode | session right | wrong | missed | outside | idle false events | utility | utility, both labs |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for cut, v in r["validation"].items():
        for lab, row in v["labs"].items():
            sess = row["session"]
            idle = "-" if row["idle_false_events"] is None else f"{row['idle_false_events']} in {row['idle_hours']:.2f} h"
            lines.append(f"| {cut} | {lab} | {row['mode']} | {sess['correct']}/{sess['expected']} | {row['session_wrong']} | "
                         f"{sess['missed']} | {sess['outside']} | {idle} | {row['utility']} | {v['utility']} |")
    same = r["dormant_cut_chosen"] == r["own_model_dormant_cut"]
    lines += ["", f"Chosen: `{r['dormant_cut_chosen']}`; `handover train` uses `{r['own_model_dormant_cut']}` "
              f"(trainer/recorded_idle.py DORMANT_CUT){'' if same else ' -- they differ: change the code or the rule'}.",
              ""]
    from benchmarks.streams_own_real import markdown as real_lines

    return lines + real_lines(r.get("real_idle_lab"), r.get("synthetic_idle_model_on_held_out_half"),
                              r.get("demo_model_on_held_out_half"))
