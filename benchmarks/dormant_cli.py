"""``./dev bench dormant``: train a 5-class model with a dormant class, and compare continuous
detection with the paper's threshold trigger on long simulated idle and mixed streams.

Steps: simulate the paper's protocol, idle streams and handover sessions (seed ``--seed``);
train the paper's 4-class model (trigger-cut windows) and the 5-class model (actions +
dormant); export both as ONNX; evaluate the 5-class model on windows leaving one subject out;
choose continuous mode's report rule on validation streams (``--val-seed``); then generate
evaluation streams with a third seed (other subjects, another hand) and replay them once,
frame by frame through the daemon's hot path, in every mode; write dormant.json, dormant.md
and figures into ``--out`` and the models into ``--out``/dormant-model/. Everything is
synthetic and labelled so.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from firmware_io.commands.options import add_quiet, progress_to
from firmware_io.errors import HandoverError
from trainer.defaults import PAPER_MODEL

__all__ = ["add_arguments", "main"]

COMMAND = "dormant"
PART_S = 900.0
"""Idle evaluation streams are generated and replayed in parts of 15 min (bounded memory)."""
RULE_GRID = {"confirm_frames": (1, 2, 3, 4, 5, 6, 8), "min_margin": (0.0, 0.25, 0.5, 1.0),
             "rearm_frames": (0, 4, 8, 16, 32)}
"""Continuous report rules tried on the validation streams."""
CRITERION = ("utility = correct first reports - wrong-class first reports - duplicates - false events, "
             "counted on the validation mixed stream plus the validation idle stream (every bad report costs "
             "what a good one gains); ties: shorter median delay, then the simpler rule "
             "(smallest confirm_frames + rearm_frames + 4 x min_margin)")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="results", help="folder for dormant.json, dormant.md, figures (default results)")
    parser.add_argument("--quick", action="store_true",
                        help="small protocol and short streams (a smoke run, a few minutes; --no-loso saves some)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the training data (protocol, idle streams)")
    parser.add_argument("--eval-seed", type=int, default=1, help="seed of the evaluation streams (unseen subjects)")
    parser.add_argument("--val-seed", type=int, default=2,
                        help="seed of the validation streams the continuous report rule is chosen on (default 2)")
    parser.add_argument("--val-events", type=int, default=None, help="events in the validation mixed stream (default 100)")
    parser.add_argument("--val-idle-hours", type=float, default=None, help="hours of validation idle stream (default 0.5)")
    parser.add_argument("--no-loso", action="store_true", help="skip the leave-one-subject-out window evaluation")
    parser.add_argument("--idle-hours", type=float, default=None, help="hours of idle evaluation stream (default 2.5)")
    parser.add_argument("--events", type=int, default=None, help="events in the mixed stream (default 100)")
    parser.add_argument("--train-idle-min", type=float, default=None, help="minutes of idle training stream (default 30)")
    parser.add_argument("--pads", default="all", help="pad selection of both models (default all)")
    parser.add_argument("--K", type=int, default=PAPER_MODEL["K"])
    parser.add_argument("--W", type=int, default=PAPER_MODEL["W"])
    parser.add_argument("--T", type=int, default=15)
    parser.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    parser.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    add_quiet(parser)


def _say(args, text: str) -> None:
    progress_to(args.quiet)(text)


def settings(args) -> dict:
    """Sizes of the run (``--quick`` shrinks the defaults; explicit options win)."""
    quick = {"runs": 1, "idle_hours": 10 / 60, "events": 12, "train_idle_min": 4.0, "train_sessions": 20,
             "val_events": 12, "val_idle_hours": 0.05}
    full = {"runs": 5, "idle_hours": 2.5, "events": 100, "train_idle_min": 30.0, "train_sessions": 100,
            "val_events": 100, "val_idle_hours": 0.5}
    s = dict(quick if args.quick else full)
    for key in ("idle_hours", "events", "train_idle_min", "val_events", "val_idle_hours"):
        if getattr(args, key) is not None:
            s[key] = getattr(args, key)
    return s


def command_line(args) -> str:
    parts = ["./dev", "bench", COMMAND, "--out", str(args.out), "--seed", str(args.seed), "--eval-seed", str(args.eval_seed),
             "--val-seed", str(args.val_seed), "--pads", args.pads, "--K", str(args.K), "--W", str(args.W), "--T", str(args.T)]
    for flag in ("idle_hours", "events", "train_idle_min", "val_events", "val_idle_hours"):
        if getattr(args, flag) is not None:
            parts += ["--" + flag.replace("_", "-"), str(getattr(args, flag))]
    if args.quick:
        parts.append("--quick")
    if args.no_loso:
        parts.append("--no-loso")
    return " ".join(parts)


def main(args: argparse.Namespace) -> int:
    if args.K < 1 or args.W < 1 or args.T - 1 < args.W:
        raise HandoverError(f"need K >= 1, W >= 1 and T >= W + 1 (got K={args.K}, W={args.W}, T={args.T})")
    s = settings(args)
    if min(s["idle_hours"], s["events"], s["train_idle_min"], s["val_events"], s["val_idle_hours"]) <= 0:
        raise HandoverError("--idle-hours, --events, --train-idle-min, --val-events and --val-idle-hours must be positive")
    if args.seed == args.eval_seed:
        raise HandoverError("--eval-seed must differ from --seed (the evaluation streams must be unseen)")
    if args.val_seed in (args.seed, args.eval_seed):
        raise HandoverError("--val-seed must differ from --seed and --eval-seed (the rule is chosen on streams of its own)")
    try:
        from firmware_io.layout import SensorLayout

        SensorLayout.sdh2().pads(args.pads)
    except ValueError as exc:
        raise HandoverError(f"--pads: {exc}") from exc
    try:
        result = run(args, s)
    except OSError as exc:
        raise HandoverError(str(exc)) from exc
    if args.json:
        print(json.dumps(result["summary"], indent=1))
    return 0


def train_models(args, s: dict, model_dir: Path) -> dict:
    """Simulate the training data, fit and export the 4-class and the 5-class models."""
    from firmware_io.sim import constants as K
    from firmware_io.sim import demo_script, simulate_protocol, simulate_session
    from firmware_io.sim.idle import simulate_idle
    from runtime.trigger_settings import PAPER_FRACTION
    from trainer import dormant
    from trainer.dataset import build_dataset

    _say(args, f"simulating the protocol ({s['runs']} run(s) per subject) and {s['train_idle_min']:g} min of idle "
               f"stream (synthetic, seed {args.seed}) ...")
    protocol = simulate_protocol(seed=args.seed, runs=s["runs"])
    n_parts = max(1, round(s["train_idle_min"] / 10))
    idle = [simulate_idle(60.0 * s["train_idle_min"] / n_parts, seed=args.seed, part=p) for p in range(n_parts)]
    sessions = [simulate_session(demo_script(s["train_sessions"], seed=args.seed, gap=(4.0, 6.0)), seed=args.seed)]
    rate = 1.0 / K.FRAME_PERIOD_S

    _say(args, "training the paper's 4-class model (threshold-cut windows) ...")
    ds = build_dataset(protocol, T=args.T, pads=args.pads, fraction=PAPER_FRACTION)
    paper = dormant.train(ds.X, ds.y, args.K, args.W, seed=args.seed)
    common = {"pads": ds.pads, "pad_sizes": ds.pad_sizes, "fullscale": ds.fullscale, "fraction": PAPER_FRACTION,
              "sample_rate_hz": rate}
    paper_path = dormant.export(paper, model_dir / "paper.onnx", dormant_class=None, **common, training={
        "data_fingerprint": ds.fingerprint, **ds.counts().to_meta(), "synthetic": True,
        "data": f"simulate_protocol(seed={args.seed}, runs={s['runs']})", "seed": args.seed,
        "C": paper.best_params_.get("C"), "gamma": paper.best_params_.get("gamma")})

    _say(args, "training the 5-class model (actions + dormant) ...")
    dds = dormant.build_dormant_dataset(protocol, idle, T=args.T, pads=args.pads, seed=args.seed, sessions=sessions)
    five = dormant.train(dds.X, dds.y, args.K, args.W, seed=args.seed)
    five_path = dormant.export(five, model_dir / "dormant.onnx", dormant_class=dormant.DORMANT, **common, training={
        "data_fingerprint": dds.fingerprint, **dds.counts(trials=ds.n_trials).to_meta(), "synthetic": True,
        "data": f"simulate_protocol(seed={args.seed}, runs={s['runs']}) + "
                f"{s['train_idle_min']:g} min simulate_idle(seed={args.seed}) + simulate_session("
                f"demo_script({s['train_sessions']}, seed={args.seed}))",
        "windows": dds.summary(), "seed": args.seed,
        "C": five.best_params_.get("C"), "gamma": five.best_params_.get("gamma")})
    loso = None
    if not args.no_loso:
        _say(args, "leave-one-subject-out of the 5-class model on windows ...")
        loso = dormant.leave_one_subject_out(dds, args.K, args.W, seed=args.seed, log=lambda m: _say(args, m))
    return {"paper_path": paper_path, "dormant_path": five_path, "loso": loso,
            "paper": {"n_cases": len(ds.y), "n_untriggered": ds.n_untriggered, "best_params": paper.best_params_},
            "dormant": {**dds.summary(), "best_params": five.best_params_}}


PLAIN_RULE = {"confirm_frames": 1, "min_margin": 0.0, "rearm_frames": 0}
"""Report every change of the per-frame decision (what the daemon did before the rule)."""


def _rule_key(rule: dict) -> tuple:
    return (rule["confirm_frames"], rule["min_margin"], rule["rearm_frames"])


def rank(row: dict) -> tuple:
    """CRITERION as a sort key (larger is better)."""
    return (row["utility"], -(row["delay_median_s"] or 1e9),
            -(row["confirm_frames"] + row["rearm_frames"] + 4 * row["min_margin"]))


def choose_rule(args, s: dict, five) -> dict:
    """Try every rule of RULE_GRID on validation streams (their own seed); keep the best by CRITERION.

    The model's per-frame decisions are computed once (batched); the rule runs offline on them
    (the daemon's own ``ContinuousDecision``; the daemon replay agrees with it, tested).
    """
    import itertools

    from firmware_io.sim import constants as K
    from firmware_io.sim import demo_script
    from firmware_io.sim.idle import simulate_idle, simulate_mixed
    from trainer import streams_eval as se

    period = K.FRAME_PERIOD_S
    _say(args, f"validation streams (synthetic, seed {args.val_seed}): {s['val_events']} events, "
               f"{s['val_idle_hours']:g} h idle ...")
    mixed = simulate_mixed(demo_script(s["val_events"], seed=args.val_seed, gap=(10.0, 20.0)), seed=args.val_seed)
    truths = se.truths_of(mixed)
    n_parts = max(1, round(3600.0 * s["val_idle_hours"] / PART_S))
    idle = [simulate_idle(3600.0 * s["val_idle_hours"] / n_parts, seed=args.val_seed, part=p) for p in range(n_parts)]
    fd_mixed = se.frame_decisions(mixed, five)
    fd_idle = [se.frame_decisions(rec, five) for rec in idle]
    rows = []
    for c, m, r in itertools.product(*RULE_GRID.values()):
        rule = {"confirm_frames": c, "min_margin": m, "rearm_frames": r}
        sm = se.score(se.apply_rule(*fd_mixed, five.meta, rule), truths, mixed.n_frames, period)
        false_idle = sum(len(se.apply_rule(*fd, five.meta, rule)) for fd in fd_idle)
        false = sm["false_events"] + false_idle
        hours = sm["idle_hours"] + sum(rec.n_frames for rec in idle) * period / 3600.0
        rows.append({**rule, "correct": sm["correct"], "wrong": sm["wrong_class"], "missed": sm["missed"],
                     "duplicates": sm["duplicates"], "false_events": false, "false_per_hour": false / hours,
                     "delay_median_s": sm["delay_s"]["median"] if sm["delay_s"] else None,
                     "utility": sm["correct"] - sm["wrong_class"] - sm["duplicates"] - false})
    best = max(rows, key=rank)
    chosen = {k: best[k] for k in RULE_GRID}
    _say(args, f"chosen rule {chosen}: utility {best['utility']} on validation")
    return {"chosen": chosen, "criterion": CRITERION, "grid": rows, "best": best,
            "plain": next(row for row in rows if _rule_key(row) == _rule_key(PLAIN_RULE)),
            "streams": {"seed": args.val_seed, "events": len(truths), "mixed_hours": mixed.n_frames * period / 3600,
                        "idle_hours": sum(rec.n_frames for rec in idle) * period / 3600}}


def evaluate(args, s: dict, models: dict, rule: dict) -> dict:
    """Replay the idle and the mixed streams through the daemon in each mode, once.

    ``continuous`` is the daemon with the chosen report rule; ``continuous_plain`` (report
    every change, the daemon's old behaviour) is computed offline from the same model's
    per-frame decisions, for comparison.
    """
    from firmware_io.sim import constants as K
    from firmware_io.sim import demo_script
    from firmware_io.sim.idle import simulate_idle, simulate_mixed
    from trainer import streams_eval as se

    period = K.FRAME_PERIOD_S
    five = models["continuous"]
    plain_idle: list[dict] = []
    idle_scores: dict[str, list[dict]] = {m: [] for m in models}
    seconds: dict[str, float] = {m: 0.0 for m in models}
    frames_total = 0
    hours_by_source: dict[str, float] = {}
    total_s = 3600.0 * s["idle_hours"]
    n_parts = max(1, round(total_s / PART_S))
    for p in range(n_parts):
        _say(args, f"idle evaluation stream part {p + 1}/{n_parts} ({total_s / n_parts / 60:.0f} min, synthetic, "
                   f"seed {args.eval_seed}) ...")
        rec = simulate_idle(total_s / n_parts, seed=args.eval_seed, part=p)
        frames_total += rec.n_frames
        for k, v in se.source_hours([rec], period).items():
            hours_by_source[k] = hours_by_source.get(k, 0.0) + v
        names = se.source_names(rec, rec.n_frames)
        for mode in models:
            t0 = time.perf_counter()
            dec = se.replay(rec, models[mode], mode, rule=rule)
            seconds[mode] += time.perf_counter() - t0
            idle_scores[mode].append(se.score(dec, [], rec.n_frames, period, names))
        plain = se.apply_rule(*se.frame_decisions(rec, five), five.meta, PLAIN_RULE)
        plain_idle.append(se.score(plain, [], rec.n_frames, period, names))
        del rec
    _say(args, f"mixed stream with {s['events']} events (synthetic, seed {args.eval_seed}) ...")
    script = demo_script(s["events"], seed=args.eval_seed, gap=(10.0, 20.0))
    mixed = simulate_mixed(script, seed=args.eval_seed)
    truths = se.truths_of(mixed)
    names = se.source_names(mixed, mixed.n_frames)
    mixed_scores, mixed_decisions = {}, {}
    for mode in models:
        t0 = time.perf_counter()
        dec = se.replay(mixed, models[mode], mode, rule=rule)
        seconds[mode] += time.perf_counter() - t0
        mixed_decisions[mode] = dec
        mixed_scores[mode] = {**se.score(dec, truths, mixed.n_frames, period, names), "latency": se.latency_stats(dec)}
    fd = se.frame_decisions(mixed, five)
    offline = se.apply_rule(*fd, five.meta, rule)
    agrees = [(d.frame, d.cls) for d in offline] == [(d.frame, d.cls) for d in mixed_decisions["continuous"]]
    plain = se.apply_rule(*fd, five.meta, PLAIN_RULE)
    mixed_decisions = {"continuous_plain": plain, **mixed_decisions}
    mixed_scores["continuous_plain"] = {**se.score(plain, truths, mixed.n_frames, period, names), "latency": None}
    idle_all = {m: se.merge_idle(idle_scores[m]) for m in models}
    idle_all["continuous_plain"] = se.merge_idle(plain_idle)
    per_frame_us = {m: 1e6 * seconds[m] / (frames_total + mixed.n_frames) for m in models}
    return {
        "offline_rule_matches_daemon": agrees,
        "idle": idle_all,
        "idle_hours_by_source": hours_by_source,
        "idle_frames": frames_total,
        "mixed": mixed_scores,
        "mixed_info": {"n_frames": mixed.n_frames, "hours": mixed.n_frames * period / 3600.0,
                       "n_events": len(truths), "script_gap_s": [10.0, 20.0]},
        "replay_us_per_frame": per_frame_us,
        "_mixed": mixed, "_truths": truths, "_decisions": mixed_decisions,
    }


def run(args, s: dict) -> dict:
    from runtime.model import load_model

    t0 = time.perf_counter()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    model_dir = out / "dormant-model"
    trained = train_models(args, s, model_dir)
    paper = load_model(trained["paper_path"])
    five = load_model(trained["dormant_path"])
    models = {"threshold": paper, "baseline": paper, "continuous": five}
    choice = choose_rule(args, s, five)
    ev = evaluate(args, s, models, choice["chosen"])
    result = {
        "synthetic": True,
        "command": command_line(args),
        "settings": {**s, "seed": args.seed, "eval_seed": args.eval_seed, "val_seed": args.val_seed,
                     "pads": args.pads, "K": args.K, "W": args.W, "T": args.T},
        "rule": choice,
        "loso": trained["loso"],
        "models": {"paper": {**trained["paper"], "file": str(trained["paper_path"]), "model_id": paper.model_id,
                             "classes": list(paper.meta.classes)},
                   "dormant": {**trained["dormant"], "file": str(trained["dormant_path"]), "model_id": five.model_id,
                               "classes": list(five.meta.classes), "dormant_class": five.meta.dormant_class}},
        **{k: v for k, v in ev.items() if not k.startswith("_")},
    }
    result["summary"] = summary(result)
    figures = {} if args.no_figures else write_figures(out, ev, models, choice)
    result["figures"] = figures
    result["seconds"] = round(time.perf_counter() - t0, 1)
    (out / "dormant.json").write_text(json.dumps(result, indent=1, default=_json_default) + "\n")
    (out / "dormant.md").write_text(markdown(result))
    _say(args, f"wrote {out / 'dormant.md'} and {out / 'dormant.json'} ({result['seconds']:.0f} s)")
    return result


def summary(r: dict) -> dict:
    """One row per mode: the figures a robot integrator asks for first."""
    rows = {}
    for mode in ORDER:
        m = r["mixed"][mode]
        rows[mode] = {
            "false_per_hour_idle_stream": r["idle"][mode]["false_per_hour"],
            "false_per_hour_mixed_idle": m["false_per_hour"],
            "recall": m["recall"], "correct_rate": m["correct_rate"], "missed": m["missed"],
            "wrong_class": m["wrong_class"], "duplicates": m["duplicates"],
            "delay_median_s": m["delay_s"]["median"] if m["delay_s"] else None,
            "delay_p90_s": m["delay_s"]["p90"] if m["delay_s"] else None,
        }
    return {"synthetic": True, "idle_hours": sum(r["idle_hours_by_source"].values()),
            "mixed_events": r["mixed_info"]["n_events"], "modes": rows}


def _json_default(x):
    import numpy as np

    if isinstance(x, np.integer | np.bool_):
        return x.item()
    if isinstance(x, np.floating):
        return float(x)
    if isinstance(x, np.ndarray):
        return x.tolist()
    return str(x)


MODE_TEXT = {
    "threshold": "threshold trigger (15 %) + 4-class model (the paper)",
    "baseline": "baseline-relative threshold trigger + 4-class model",
    "continuous_plain": "continuous, 5-class model, report every change (no rule; offline)",
    "continuous": "continuous, 5-class model + report rule (chosen on validation)",
}
ORDER = ("threshold", "baseline", "continuous_plain", "continuous")


def _fmt(x, spec: str = ".2f") -> str:
    return "-" if x is None else format(x, spec)


def markdown(r: dict) -> str:
    s = r["settings"]
    lines = [
        "# Dormant class and continuous detection vs the threshold trigger (synthetic)",
        "",
        "All data here are **synthetic** (the simulated hand, `firmware_io.sim` and `firmware_io.sim.idle`; "
        "docs/DORMANT.md). Reproduce with:",
        "",
        f"    {r['command']}",
        "",
        f"Training: seed {s['seed']} (protocol, {s['runs']} run(s) per subject x 5 subjects; "
        f"{s['train_idle_min']:g} min of idle stream; a session of {s['train_sessions']} handovers for the hand "
        f"closing / opening around an action). Rule choice: validation streams, seed {s['val_seed']}. "
        f"Evaluation: seed {s['eval_seed']}, i.e. subjects and a hand never seen in training or validation, run once. "
        "Every stream is replayed frame by frame through the daemon's own hot path "
        "(`runtime.daemon.Daemon.handle_frame`: ring, trigger, ONNX model, continuous report rule); "
        "`continuous_plain` is the same model's per-frame decisions with the old report-every-change rule "
        f"(computed offline; the offline rule reproduces the daemon's reports exactly on this stream: "
        f"{r.get('offline_rule_matches_daemon')}).",
        "",
        f"- idle stream: {r['summary']['idle_hours']:.2f} h of a hand holding objects nobody touches "
        "(noise, creep, drift, arm moves, regrasps, grasp/release, open hand);",
        f"- mixed stream: {r['mixed_info']['n_events']} scripted events (unseen subjects), idle holds in between "
        f"({r['mixed_info']['hours']:.2f} h).",
        "",
        "| mode | false events / h (idle stream) | false / h (mixed, idle part) | detected | correct class | missed | "
        "wrong class | duplicates | delay median (s) | delay p90 (s) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for mode, row in r["summary"]["modes"].items():  # ORDER
        m = r["mixed"][mode]
        lines.append(
            f"| {MODE_TEXT[mode]} | {_fmt(row['false_per_hour_idle_stream'], '.1f')} | "
            f"{_fmt(row['false_per_hour_mixed_idle'], '.1f')} | {m['detected']}/{m['n_events']} | "
            f"{m['correct']}/{m['n_events']} | {m['missed']} | {m['wrong_class']} | {m['duplicates']} | "
            f"{_fmt(row['delay_median_s'])} | {_fmt(row['delay_p90_s'])} |")
    lines += ["", "Delay: from the annotated onset of the person's action to the frame that ended the classified "
              "window (the decision). False events: reported events outside `[onset - 2 frames, end of the event]`.",
              "", "## False events in the idle stream by what was going on (events per hour of that situation)", "",
              "| source | hours | " + " | ".join(ORDER) + " |", "|---|---|" + "---|" * len(ORDER)]
    hours = r["idle_hours_by_source"]
    for src in sorted(hours):
        cells = []
        for mode in ORDER:
            n = r["idle"][mode]["false_by_source"].get(src, 0)
            cells.append(f"{n} ({n / hours[src]:.0f}/h)" if hours[src] > 0 else str(n))
        lines.append(f"| {src} | {hours[src]:.2f} | " + " | ".join(cells) + " |")
    lines += ["", "## Per action (mixed stream): detected / correct of n", "",
              "| action | " + " | ".join(ORDER) + " |", "|---|" + "---|" * len(ORDER)]
    actions = sorted(next(iter(r["mixed"].values()))["per_action"])
    for a in actions:
        cells = [f"{r['mixed'][m]['per_action'][a]['detected']} / {r['mixed'][m]['per_action'][a]['correct']} of "
                 f"{r['mixed'][m]['per_action'][a]['n']}" for m in ORDER]
        lines.append(f"| {a} | " + " | ".join(cells) + " |")
    lines += ["", "## Cost", "", "| mode | replay time per frame (us, whole hot path incl. Python) | decision latency "
              "median / p99 (us, reported events) |", "|---|---|---|"]
    for mode in r["replay_us_per_frame"]:
        lat = r["mixed"][mode]["latency"]
        lat_txt = f"{lat['median_us']:.0f} / {lat['p99_us']:.0f}" if lat else "-"
        lines.append(f"| {mode} | {r['replay_us_per_frame'][mode]:.1f} | {lat_txt} |")
    lines += rule_section(r) + loso_section(r)
    d = r["models"]["dormant"]
    lines += ["", "## Models", "",
              f"- paper (4 classes): {r['models']['paper']['n_cases']} trigger-cut cases "
              f"({r['models']['paper']['n_untriggered']} trials never triggered), SVM {r['models']['paper']['best_params']}.",
              f"- dormant (5 classes {d['classes']}): {d['n_cases']} windows, per class {d['per_class']}, "
              f"per origin {d['per_origin']}, SVM {d['best_params']}.",
              "", "Both exported as one ONNX graph each (`dormant-model/paper.onnx`, `dormant-model/dormant.onnx`, "
              "not committed: `./dev bench dormant` rewrites them).", ""]
    for title, name in r.get("figures", {}).items():
        lines += [f"## {title}", "", f"![{title}]({name})", ""]
    return "\n".join(lines)


def rule_section(r: dict) -> list[str]:
    rule = r["rule"]
    c = rule["chosen"]
    v = rule["streams"]
    grid = sorted(rule["grid"], key=rank, reverse=True)
    lines = ["", "## Continuous mode's report rule: how it was chosen", "",
             f"Chosen: `confirm_frames = {c['confirm_frames']}`, `min_margin = {c['min_margin']:g}`, "
             f"`rearm_frames = {c['rearm_frames']}` (runtime/decision.py; `[continuous]` in deploy/handover.toml).",
             "",
             f"Chosen once, before the evaluation streams were generated, on validation streams of their own seed "
             f"({v['seed']}: {v['events']} events in {v['mixed_hours']:.2f} h of mixed stream + {v['idle_hours']:.2f} h "
             f"of idle stream, synthetic) over the grid {dict(RULE_GRID)}; criterion: {rule['criterion']}.",
             "", "Validation (synthetic), the best ten rules and the plain report-every-change rule:", "",
             "| confirm | margin | rearm | correct | wrong | missed | duplicates | false events | false / h | "
             "delay median (s) | utility |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in [*grid[:10], rule["plain"]]:
        lines.append(f"| {row['confirm_frames']} | {row['min_margin']:g} | {row['rearm_frames']} | {row['correct']} | "
                     f"{row['wrong']} | {row['missed']} | {row['duplicates']} | {row['false_events']} | "
                     f"{row['false_per_hour']:.1f} | {_fmt(row['delay_median_s'])} | {row['utility']} |")
    return lines


def loso_section(r: dict) -> list[str]:
    lo = r.get("loso")
    if not lo:
        return ["", "## Leave-one-subject-out (windows)", "", "Not run (`--no-loso`)."]
    classes = lo["classes"]
    lines = ["", "## The 5-class model on windows, leave one subject out (synthetic)", "",
             "Fold i holds out subject i's protocol and session windows and the i-th fifth of the idle streams; "
             "the model (C, gamma by its own inner cross-validation) is trained on the rest. One simulated hand "
             f"throughout. Accuracy {lo['accuracy_mean']:.3f} +/- {lo['accuracy_std']:.3f} over folds.", "",
             "| true \\ predicted | " + " | ".join(classes) + " | recall |", "|---|" + "---|" * (len(classes) + 1)]
    for k, c in enumerate(classes):
        lines.append(f"| {c} | " + " | ".join(str(n) for n in lo["confusion"][k]) + f" | {_fmt(lo['recall'][c])} |")
    lines += ["", "Recall by where the window came from:", "", "| origin | windows | recall |", "|---|---|---|"]
    for o, rec in lo["recall_by_origin"].items():
        lines.append(f"| {o} | {lo['n_by_origin'][o]} | {_fmt(rec)} |")
    return lines


def write_figures(out: Path, ev: dict, models: dict, rule: dict) -> dict[str, str]:
    from benchmarks import dormant_plots

    return {
        "Report rules on the validation streams (synthetic)": dormant_plots.rule_grid(
            out / "dormant_rules.png", rule["grid"], rule["chosen"]),
        "Timeline of the mixed stream (synthetic)": dormant_plots.timeline(
            out / "dormant_timeline.png", ev["_mixed"], ev["_truths"], ev["_decisions"], models["continuous"].meta.pads),
        "False events per hour vs detection delay (synthetic)": dormant_plots.tradeoff(
            out / "dormant_tradeoff.png", ev["idle"], ev["mixed"]),
        "False events by idle source (synthetic)": dormant_plots.false_by_source(
            out / "dormant_sources.png", ev["idle"], ev["idle_hours_by_source"]),
    }
