"""``./dev bench streams``: events in a live stream: the right one, once, from the person's onset.

Every stream is replayed frame by frame through the real daemon (``trainer.streams_eval.replay``:
``Daemon.serve`` + ``handle_frame``), in every mode (``streams_eval.MODES``):

1. models (synthetic, training seed): the default model's estimator trained on windows cut by
   the onset trigger (``onset`` modes) and by the paper's threshold (``threshold``, ``baseline``);
   a 5-class model with a dormant class and per-pad level features for ``continuous``;
2. validation streams (their own seed): a mixed stream (scripted events by simulated subjects,
   idle holds between them) and an idle stream; the default stream setting is chosen here by
   ``CRITERION``, among the settings the daemon runs alone (the robot's messages are optional);
3. test streams (another seed: unseen subjects, another hand), run once: per-class precision,
   recall and F1 of reported events, onset-to-report frames, duplicates, false events per hour;
4. the demo's scripted session (40 events, ``handover demo``'s seed) with the chosen setting;
5. every real SDH-2 recording in ../shared/data (none holds a human handover): false events per hour.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from trainer import streams_eval as se
from trainer.measure import command_line, load_average, load_note, machine_info, write_results
from trainer.shared_data import real_files

NAME = "streams"
VAL_OFFSET, TEST_OFFSET = 2, 1
"""Validation streams use seed + 2, test streams seed + 1 (the training data use the seed itself)."""
CANDIDATES = ("threshold", "baseline", "onset", "onset_dormant", "continuous")
"""Stream settings the daemon runs without any input but the pads (the default must not need the robot)."""
CRITERION = ("utility = right first reports - wrong first reports - duplicates - false events, on the validation "
             "mixed stream plus the validation idle stream (synthetic) plus the real validation recordings (every "
             "other real file in sorted order, none holds a handover: every event there is false); every bad report "
             "costs what a good one gains; ties: the shorter median onset-to-report time")
PART_S = 900.0
SIZES = {
    "full": {"runs": 5, "train_idle_min": 10.0, "train_sessions": 60, "val_events": 60, "val_idle_h": 0.25,
             "test_events": 200, "test_idle_h": 1.0},
    "quick": {"runs": 1, "train_idle_min": 3.0, "train_sessions": 12, "val_events": 12, "val_idle_h": 0.05,
              "test_events": 12, "test_idle_h": 0.05},
}
"""The full test mixed stream holds 50 events per action: with 25, a class's recall of 0.9 has a 95 %
interval of about +/- 0.14 (``trainer.rate_interval.proportion_interval``), too wide to judge a bar."""


def train_models(work: Path, seed: int, s: dict, say) -> dict:
    """Export and load the three models every mode needs (synthetic training data, ``seed``)."""
    from benchmarks.pareto import DEFAULT_PARAMS
    from firmware_io.sim import simulate_protocol
    from runtime.model import load_model
    from runtime.trigger_settings import PAPER_FRACTION
    from trainer import dormant
    from trainer.classifier import BowSVC
    from trainer.dataset import build_dataset
    from trainer.measure import export_metadata
    from trainer.onnx_export import export_onnx

    protocol = simulate_protocol(seed=seed, runs=s["runs"])
    paths = {}
    for name, fraction in (("onset", None), ("threshold", PAPER_FRACTION)):
        say(f"streams: training the default model on {name}-cut windows (synthetic, seed {seed}) ...")
        ds = build_dataset(protocol, T=DEFAULT_PARAMS["T"], pads=DEFAULT_PARAMS["pads"], fraction=fraction)
        model = _default_estimator(BowSVC, ds.pad_sizes, seed).fit(ds.X, ds.y)
        paths[name] = export_onnx(model, work / f"{name}.onnx", export_metadata(ds, model, seed=seed))
    say(f"streams: training the 5-class model (dormant, level features) on {s['train_idle_min']:g} min of idle "
        f"stream and {s['train_sessions']} handovers ...")
    paths["continuous"] = dormant.fit_stream_model(protocol, seed, s["train_idle_min"], s["train_sessions"],
                                                   work / "dormant.onnx")
    loaded = {k: load_model(p) for k, p in paths.items()}
    return {"threshold": loaded["threshold"], "baseline": loaded["threshold"], "onset": loaded["onset"],
            "onset_robot": loaded["onset"], "onset_dormant": loaded["continuous"], "continuous": loaded["continuous"],
            "onset_arm": loaded["onset"], "onset_dormant_arm": loaded["continuous"],
            "continuous_arm": loaded["continuous"]}


def _default_estimator(cls, pad_sizes, seed: int, **options):
    """The product's default estimator (benchmarks.pareto.DEFAULT_PARAMS), plus ``options``."""
    from benchmarks.pareto import DEFAULT_PARAMS as P

    return cls(n_words=P["K"], window=P["W"], kernel=P["kernel"], per_pad=P["per_pad"], pad_sizes=pad_sizes,
               random_state=seed, **options)


def evaluate_sim(models: dict, seed: int, n_events: int, idle_h: float, say, label: str,
                 rule: dict | None = None) -> dict:
    """Every mode on a mixed stream of ``n_events`` and ``idle_h`` hours of idle stream (seed ``seed``);
    ``rule``: continuous mode's report rule (None: the config's)."""
    from firmware_io.sim import constants as K
    from firmware_io.sim import demo_script
    from firmware_io.sim.idle import simulate_idle, simulate_mixed

    period = K.FRAME_PERIOD_S
    say(f"streams: {label} mixed stream, {n_events} events (synthetic, seed {seed}) ...")
    mixed = simulate_mixed(demo_script(n_events, seed=seed, gap=(10.0, 20.0)), seed=seed)
    truths = se.truths_of(mixed)
    names = se.source_names(mixed, mixed.n_frames)
    out: dict = {m: {} for m in se.MODES}
    for mode in se.MODES:
        sc = se.score(se.replay(mixed, models[mode], mode, rule=rule), truths, mixed.n_frames, period, names)
        out[mode] = {"mixed": sc, "f1": se.macro_f1(sc["per_class"])}
    idle_scores: dict[str, list] = {m: [] for m in se.MODES}
    source_hours: dict[str, float] = {}
    n_parts = max(1, round(3600.0 * idle_h / PART_S))
    for p in range(n_parts):
        say(f"streams: {label} idle stream part {p + 1}/{n_parts} (synthetic, seed {seed}) ...")
        rec = simulate_idle(3600.0 * idle_h / n_parts, seed=seed, part=p)
        names = se.source_names(rec, rec.n_frames)
        for k, v in se.source_hours([rec], period).items():
            source_hours[k] = source_hours.get(k, 0.0) + v
        for mode in se.MODES:
            idle_scores[mode].append(se.score(se.replay(rec, models[mode], mode, rule=rule), [], rec.n_frames, period,
                                              names))
    for mode in se.MODES:
        idle = se.merge_idle(idle_scores[mode])
        m = out[mode]["mixed"]
        false = m["false_events"] + idle["false_events"]
        hours = m["idle_hours"] + idle["idle_hours"]
        out[mode].update(idle=idle, false_per_hour=false / hours if hours else None,
                         utility=m["correct"] - m["wrong_class"] - m["duplicates"] - false)
        arm_h = source_hours.get("arm_move", 0.0)
        out[mode]["idle"]["arm_move_false_per_hour"] = (out[mode]["idle"]["false_by_source"].get("arm_move", 0) / arm_h
                                                        if arm_h else None)
    out["_info"] = {"seed": seed, "events": len(truths), "mixed_hours": mixed.n_frames * period / 3600.0,
                    "idle_hours": sum(s["idle_hours"] for s in idle_scores[se.MODES[0]]),
                    "idle_source_hours": source_hours}
    return out


def choose_continuous_rule(model, seed: int, s: dict, say) -> dict:
    """Continuous mode's report rule on validation streams (benchmarks.streams_rule)."""
    from benchmarks.streams_rule import choose_rule
    from firmware_io.sim.idle import simulate_idle

    n_parts = max(1, round(3600.0 * s["val_idle_h"] / PART_S))
    idle = [simulate_idle(3600.0 * s["val_idle_h"] / n_parts, seed=seed, part=p) for p in range(n_parts)]
    return choose_rule(model, seed, idle, say)


def choose(val: dict, real: dict | None) -> str:
    """CRITERION over CANDIDATES on the validation streams and the real validation recordings."""
    for mode in CANDIDATES:
        real_false = real["split"]["validation"]["events"].get(mode, 0) if real else 0
        val[mode]["real_validation_false_events"] = real_false
        val[mode]["utility_with_real"] = val[mode]["utility"] - real_false

    def key(mode: str) -> tuple:
        d = val[mode]["mixed"]["delay_frames"]
        return (val[mode]["utility_with_real"], -(d["median"] if d else 1e9))

    return max(CANDIDATES, key=key)


def demo_session(models: dict, mode: str, seed: int) -> dict:
    """``handover demo``'s scripted session (its seed, 40 events), in-process through the daemon."""
    from trainer.commands.demo_cli import scripted_session

    session_seed, _, session = scripted_session(seed)
    out = {"mode": mode, "seed": session_seed}
    for m in dict.fromkeys((mode, "threshold", "onset", "onset_robot")):
        out[m] = se.session_outcomes(se.replay(session, models[m], m), session.trials)
    return out


def evaluate_real(models: dict, root: Path, say) -> dict:
    """False events per hour of every real recording (none holds a handover), each mode but onset_robot."""
    from firmware_io.recordings.importers import import_any

    modes = [m for m in se.MODES if m != "onset_robot" and m not in se.ARM_MODES]  # no robot messages were recorded
    rows = []
    for k, (path, cat, why) in enumerate(real_files(root)):
        try:
            rec = import_any(path)
        except Exception as exc:  # a file the importers refuse is listed, not counted
            rows.append({"file": str(path.relative_to(root)), "category": cat, "skipped": str(exc)})
            continue
        hours = float(rec.timestamps[-1] - rec.timestamps[0]) / 3600.0 if rec.n_frames > 1 else 0.0
        row = {"file": str(path.relative_to(root)), "category": cat, "why_idle": why, "frames": rec.n_frames,
               "hours": hours, "split": "validation" if k % 2 == 0 else "test", "events": {}}
        for mode in modes:
            try:
                row["events"][mode] = [d.cls for d in se.replay(rec, models[mode], mode)]
            except ValueError as exc:
                row.setdefault("skipped_modes", {})[mode] = str(exc)
        rows.append(row)
    say(f"streams: {len(rows)} real recordings replayed")
    used = [r for r in rows if "events" in r]
    hours = sum(r["hours"] for r in used)
    per_mode = {m: sum(len(r["events"].get(m, ())) for r in used) for m in modes}
    by_cat: dict[str, dict] = {}
    for r in used:
        c = by_cat.setdefault(r["category"], {"files": 0, "hours": 0.0, **{m: 0 for m in modes}})
        c["files"] += 1
        c["hours"] += r["hours"]
        for m in modes:
            c[m] += len(r["events"].get(m, ()))
    split = {}
    for name in ("validation", "test"):
        part = [r for r in used if r["split"] == name]
        h = sum(r["hours"] for r in part)
        n = {m: sum(len(r["events"].get(m, ())) for r in part) for m in modes}
        split[name] = {"files": len(part), "hours": h, "events": n,
                       "false_per_hour": {m: n[m] / h if h else None for m in modes}}
    at_rate = [r for r in used if r["category"] != "fast"]
    hours_at_rate = sum(r["hours"] for r in at_rate)
    per_mode_at_rate = {m: sum(len(r["events"].get(m, ())) for r in at_rate) for m in modes}
    return {"root": str(root), "files": len(used), "hours": hours, "events": per_mode,
            "false_per_hour": {m: per_mode[m] / hours if hours else None for m in modes},
            "hours_at_model_rate": hours_at_rate,
            "false_per_hour_at_model_rate": {m: per_mode_at_rate[m] / hours_at_rate if hours_at_rate else None
                                             for m in modes},
            "by_category": by_cat, "split": split, "rows": rows}


def run(args) -> dict:
    from trainer.shared_data import default_data_dir

    say = args.say
    s = SIZES["quick" if args.quick else "full"]
    load_before = load_average()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="handover-streams-") as tmp:
        models = train_models(Path(tmp), args.seed, s, say)
        rule = choose_continuous_rule(models["continuous"], args.seed + VAL_OFFSET, s, say)
        val = evaluate_sim(models, args.seed + VAL_OFFSET, s["val_events"], s["val_idle_h"], say, "validation",
                           rule["chosen"])
        root = default_data_dir()
        real = evaluate_real(models, root, say) if root.is_dir() else None
        chosen = choose(val, real)
        say(f"streams: chosen stream setting on validation: {chosen}")
        test = evaluate_sim(models, args.seed + TEST_OFFSET, s["test_events"], s["test_idle_h"], say, "test",
                            rule["chosen"])
        demo = demo_session(models, chosen, args.seed)
    result = summary(test, chosen, demo, real)
    result.update(continuous_rule=rule["chosen"], continuous_rule_in_code=rule["shipped"], continuous_rule_choice=rule)
    from benchmarks.streams_own import own_keys

    result.update(own_keys(args.out))  # the own-data model's figures (bench streams_own) stay in this file
    from runtime.trigger_settings import resolve_trigger

    result.update(synthetic_streams=True, sizes=s, seed=args.seed, machine=machine_info(),
                  onset_trigger=resolve_trigger().to_meta(),
                  command=command_line(NAME, args), load_before=load_before, load_after=load_average(),
                  seconds=round(time.perf_counter() - t0, 1), criterion=CRITERION, candidates=list(CANDIDATES),
                  validation=val, test=test, demo=demo, real=real)
    from benchmarks.streams_report import markdown

    write_results(args.out, NAME, result, markdown(result, load_note(load_before, result["load_after"],
                                                                     result["machine"]["cores"])))
    return result


def summary(test: dict, chosen: str, demo: dict, real: dict | None) -> dict:
    """The headline figures (keys the issue asks for)."""
    cont = test["continuous"]["mixed"]
    hold = cont["per_action"].get("hold", {"n": 0, "correct": 0})
    d = demo[chosen]
    from trainer.rate_interval import proportion_interval
    from trainer.streams_eval import DEFAULT_SETTING

    return {
        "default_setting": chosen,
        "default_setting_in_code": DEFAULT_SETTING,
        "demo_events_correct_fraction": d["correct_fraction"],
        "demo_events_outside": d["outside"],
        "demo_repeats": d["repeats"],
        "sim_event_f1": {m: test[m]["f1"] for m in se.MODES},
        "sim_events_correct_fraction": {m: test[m]["mixed"]["correct_rate"] for m in se.MODES},
        "sim_false_per_hour": {m: test[m]["false_per_hour"] for m in se.MODES},
        "sim_duplicates": {m: test[m]["mixed"]["duplicates"] for m in se.MODES},
        "onset_to_report_median_frames": {m: (test[m]["mixed"]["delay_frames"] or {}).get("median")
                                          for m in se.MODES},
        "onset_to_report_p90_frames": {m: (test[m]["mixed"]["delay_frames"] or {}).get("p90") for m in se.MODES},
        "continuous_hold_recall": hold["correct"] / hold["n"] if hold["n"] else None,
        "continuous_hold_counts": [hold["correct"], hold["n"]],
        "continuous_hold_recall_95": proportion_interval(hold["correct"], hold["n"]) if hold["n"] else None,
        "sim_arm_move_hours": test["_info"]["idle_source_hours"].get("arm_move"),
        "sim_arm_move_false_per_hour": {m: test[m]["idle"]["arm_move_false_per_hour"] for m in se.MODES},
        "continuous_events_correct_fraction": cont["correct_rate"],
        "real_idle_hours": real["hours"] if real else None,
        "real_idle_false_events_per_hour": real["false_per_hour"].get(chosen) if real else None,
        "real_idle_false_events_per_hour_by_mode": real["false_per_hour"] if real else None,
        "real_idle_false_events_per_hour_at_model_rate": real["false_per_hour_at_model_rate"] if real else None,
        "real_test_half_hours": real["split"]["test"]["hours"] if real else None,
        "real_test_half_false_events_per_hour": real["split"]["test"]["false_per_hour"].get(chosen) if real else None,
    }
