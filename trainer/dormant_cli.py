"""``handover dormant``: train a 5-class model with a dormant class, and compare continuous
detection with the paper's threshold trigger on long simulated idle and mixed streams.

Steps: simulate the paper's protocol and idle streams (seed ``--seed``); train the paper's
4-class model (trigger-cut windows) and the 5-class model (actions + dormant); export both
as ONNX; generate evaluation streams with another seed (other subjects, another hand); replay
them frame by frame through the daemon's hot path in three modes; write dormant.json,
dormant.md and figures into ``--out`` and the models into ``--out``/dormant-model/.
Everything is synthetic and labelled so.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

COMMAND = "dormant"
PART_S = 900.0
"""Idle evaluation streams are generated and replayed in parts of 15 min (bounded memory)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="results", help="folder for dormant.json, dormant.md, figures (default results)")
    parser.add_argument("--quick", action="store_true", help="small protocol and short streams (a smoke run, ~30 s)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the training data (protocol, idle streams)")
    parser.add_argument("--eval-seed", type=int, default=1, help="seed of the evaluation streams (unseen subjects)")
    parser.add_argument("--idle-hours", type=float, default=None, help="hours of idle evaluation stream (default 2.5)")
    parser.add_argument("--events", type=int, default=None, help="events in the mixed stream (default 100)")
    parser.add_argument("--train-idle-min", type=float, default=None, help="minutes of idle training stream (default 30)")
    parser.add_argument("--pads", default="all", help="pad selection of both models (default all)")
    parser.add_argument("--K", type=int, default=10)
    parser.add_argument("--W", type=int, default=7)
    parser.add_argument("--T", type=int, default=15)
    parser.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    parser.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    parser.add_argument("--quiet", action="store_true")


def _fail(message: str) -> int:
    print(f"handover {COMMAND}: {message}", file=sys.stderr)
    return 2


def _say(args, text: str) -> None:
    if not args.quiet:
        print(text, file=sys.stderr, flush=True)


def settings(args) -> dict:
    """Sizes of the run (``--quick`` shrinks the defaults; explicit options win)."""
    quick = {"runs": 1, "idle_hours": 10 / 60, "events": 12, "train_idle_min": 4.0}
    full = {"runs": 5, "idle_hours": 2.5, "events": 100, "train_idle_min": 30.0}
    s = dict(quick if args.quick else full)
    for key in ("idle_hours", "events", "train_idle_min"):
        if getattr(args, key) is not None:
            s[key] = getattr(args, key)
    return s


def command_line(args) -> str:
    parts = ["handover", COMMAND, "--out", str(args.out), "--seed", str(args.seed), "--eval-seed", str(args.eval_seed),
             "--pads", args.pads, "--K", str(args.K), "--W", str(args.W), "--T", str(args.T)]
    for flag in ("idle_hours", "events", "train_idle_min"):
        if getattr(args, flag) is not None:
            parts += ["--" + flag.replace("_", "-"), str(getattr(args, flag))]
    if args.quick:
        parts.append("--quick")
    return " ".join(parts)


def main(args: argparse.Namespace) -> int:
    if args.K < 1 or args.W < 1 or args.T - 1 < args.W:
        return _fail(f"need K >= 1, W >= 1 and T >= W + 1 (got K={args.K}, W={args.W}, T={args.T})")
    s = settings(args)
    if s["idle_hours"] <= 0 or s["events"] < 1 or s["train_idle_min"] <= 0:
        return _fail("--idle-hours, --events and --train-idle-min must be positive")
    if args.seed == args.eval_seed:
        return _fail("--eval-seed must differ from --seed (the evaluation streams must be unseen)")
    try:
        from firmware_io.layout import SensorLayout

        SensorLayout.sdh2().pads(args.pads)
    except ValueError as exc:
        return _fail(f"--pads: {exc}")
    try:
        result = run(args, s)
    except OSError as exc:
        return _fail(str(exc))
    if args.json:
        print(json.dumps(result["summary"], indent=1))
    return 0


def train_models(args, s: dict, model_dir: Path) -> dict:
    """Simulate the training data, fit and export the 4-class and the 5-class models."""
    from firmware_io.sim import constants as K
    from firmware_io.sim.idle import simulate_idle
    from firmware_io.simulate import simulate_protocol
    from trainer import dormant
    from trainer.dataset import build_dataset

    _say(args, f"simulating the protocol ({s['runs']} run(s) per subject) and {s['train_idle_min']:g} min of idle "
               f"stream (synthetic, seed {args.seed}) ...")
    protocol = simulate_protocol(seed=args.seed, runs=s["runs"])
    n_parts = max(1, round(s["train_idle_min"] / 10))
    idle = [simulate_idle(60.0 * s["train_idle_min"] / n_parts, seed=args.seed, part=p) for p in range(n_parts)]
    rate = 1.0 / K.FRAME_PERIOD_S

    _say(args, "training the paper's 4-class model (threshold-cut windows) ...")
    ds = build_dataset(protocol, T=args.T, pads=args.pads, fraction=0.15)
    paper = dormant.train(ds.X, ds.y, args.K, args.W, seed=args.seed)
    common = {"pads": ds.pads, "pad_sizes": ds.pad_sizes, "fullscale": ds.fullscale, "fraction": 0.15,
              "sample_rate_hz": rate}
    paper_path = dormant.export(paper, model_dir / "paper.onnx", dormant_class=None, **common, training={
        "data_fingerprint": ds.fingerprint, "n_trials": ds.n_trials, "n_cases": len(ds.y), "synthetic": True,
        "data": f"simulate_protocol(seed={args.seed}, runs={s['runs']})", "seed": args.seed,
        "C": paper.best_params_.get("C"), "gamma": paper.best_params_.get("gamma")})

    _say(args, "training the 5-class model (actions + dormant) ...")
    dds = dormant.build_dormant_dataset(protocol, idle, T=args.T, pads=args.pads, seed=args.seed)
    five = dormant.train(dds.X, dds.y, args.K, args.W, seed=args.seed)
    five_path = dormant.export(five, model_dir / "dormant.onnx", dormant_class=dormant.DORMANT, **common, training={
        "data_fingerprint": dds.fingerprint, "n_trials": ds.n_trials, "n_cases": len(dds.y), "synthetic": True,
        "data": f"simulate_protocol(seed={args.seed}, runs={s['runs']}) + "
                f"{s['train_idle_min']:g} min simulate_idle(seed={args.seed})",
        "windows": dds.summary(), "seed": args.seed,
        "C": five.best_params_.get("C"), "gamma": five.best_params_.get("gamma")})
    return {"paper_path": paper_path, "dormant_path": five_path,
            "paper": {"n_cases": len(ds.y), "n_untriggered": ds.n_untriggered, "best_params": paper.best_params_},
            "dormant": {**dds.summary(), "best_params": five.best_params_}}


def evaluate(args, s: dict, models: dict) -> dict:
    """Replay the idle and the mixed streams through the daemon in each mode."""
    from firmware_io.sim import constants as K
    from firmware_io.sim.idle import simulate_idle, simulate_mixed
    from firmware_io.simulate import demo_script
    from trainer import streams_eval as se

    period = K.FRAME_PERIOD_S
    idle_scores: dict[str, list[dict]] = {m: [] for m in se.MODES}
    seconds: dict[str, float] = {m: 0.0 for m in se.MODES}
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
        for mode in se.MODES:
            t0 = time.perf_counter()
            dec = se.replay(rec, models[mode], mode)
            seconds[mode] += time.perf_counter() - t0
            idle_scores[mode].append(se.score(dec, [], rec.n_frames, period, names))
        del rec
    _say(args, f"mixed stream with {s['events']} events (synthetic, seed {args.eval_seed}) ...")
    script = demo_script(s["events"], seed=args.eval_seed, gap=(10.0, 20.0))
    mixed = simulate_mixed(script, seed=args.eval_seed)
    truths = se.truths_of(mixed)
    names = se.source_names(mixed, mixed.n_frames)
    mixed_scores, mixed_decisions = {}, {}
    for mode in se.MODES:
        t0 = time.perf_counter()
        dec = se.replay(mixed, models[mode], mode)
        seconds[mode] += time.perf_counter() - t0
        mixed_decisions[mode] = dec
        mixed_scores[mode] = {**se.score(dec, truths, mixed.n_frames, period, names), "latency": se.latency_stats(dec)}
    per_frame_us = {m: 1e6 * seconds[m] / (frames_total + mixed.n_frames) for m in se.MODES}
    return {
        "idle": {m: se.merge_idle(idle_scores[m]) for m in se.MODES},
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
    ev = evaluate(args, s, models)
    result = {
        "synthetic": True,
        "command": command_line(args),
        "settings": {**s, "seed": args.seed, "eval_seed": args.eval_seed, "pads": args.pads, "K": args.K, "W": args.W,
                     "T": args.T},
        "models": {"paper": {**trained["paper"], "file": str(trained["paper_path"]), "model_id": paper.model_id,
                             "classes": list(paper.meta.classes)},
                   "dormant": {**trained["dormant"], "file": str(trained["dormant_path"]), "model_id": five.model_id,
                               "classes": list(five.meta.classes), "dormant_class": five.meta.dormant_class}},
        **{k: v for k, v in ev.items() if not k.startswith("_")},
    }
    result["summary"] = summary(result)
    figures = {} if args.no_figures else write_figures(out, ev, models)
    result["figures"] = figures
    result["seconds"] = round(time.perf_counter() - t0, 1)
    (out / "dormant.json").write_text(json.dumps(result, indent=1, default=_json_default) + "\n")
    (out / "dormant.md").write_text(markdown(result))
    _say(args, f"wrote {out / 'dormant.md'} and {out / 'dormant.json'} ({result['seconds']:.0f} s)")
    return result


def summary(r: dict) -> dict:
    """One row per mode: the figures a robot integrator asks for first."""
    rows = {}
    for mode in r["idle"]:
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
    "continuous": "continuous, 5-class model with a dormant class",
}


def _fmt(x, spec: str = ".2f") -> str:
    return "-" if x is None else format(x, spec)


def markdown(r: dict) -> str:
    s = r["settings"]
    lines = [
        "# Dormant class and continuous detection vs the threshold trigger (synthetic)",
        "",
        "All data here are **synthetic** (the simulated hand, `firmware_io.simulate` and `firmware_io.sim.idle`; "
        "docs/DORMANT.md). Reproduce with:",
        "",
        f"    {r['command']}",
        "",
        f"Training: seed {s['seed']} (protocol, {s['runs']} run(s) per subject x 5 subjects; "
        f"{s['train_idle_min']:g} min of idle stream). Evaluation: seed {s['eval_seed']}, i.e. subjects and a hand "
        "never seen in training. Every stream is replayed frame by frame through the daemon's own hot path "
        "(`runtime.daemon.Daemon.handle_frame`: ring, trigger, ONNX model, report-on-change).",
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
    for mode, row in r["summary"]["modes"].items():
        m = r["mixed"][mode]
        lines.append(
            f"| {MODE_TEXT[mode]} | {_fmt(row['false_per_hour_idle_stream'], '.1f')} | "
            f"{_fmt(row['false_per_hour_mixed_idle'], '.1f')} | {m['detected']}/{m['n_events']} | "
            f"{m['correct']}/{m['n_events']} | {m['missed']} | {m['wrong_class']} | {m['duplicates']} | "
            f"{_fmt(row['delay_median_s'])} | {_fmt(row['delay_p90_s'])} |")
    lines += ["", "Delay: from the annotated onset of the person's action to the frame that ended the classified "
              "window (the decision). False events: reported events outside `[onset - 2 frames, end of the event]`.",
              "", "## False events in the idle stream by what was going on (events per hour of that situation)", "",
              "| source | hours | " + " | ".join(r["idle"]) + " |", "|---|---|" + "---|" * len(r["idle"])]
    hours = r["idle_hours_by_source"]
    for src in sorted(hours):
        cells = []
        for mode in r["idle"]:
            n = r["idle"][mode]["false_by_source"].get(src, 0)
            cells.append(f"{n} ({n / hours[src]:.0f}/h)" if hours[src] > 0 else str(n))
        lines.append(f"| {src} | {hours[src]:.2f} | " + " | ".join(cells) + " |")
    lines += ["", "## Per action (mixed stream): detected / correct of n", "",
              "| action | " + " | ".join(r["mixed"]) + " |", "|---|" + "---|" * len(r["mixed"])]
    actions = sorted(next(iter(r["mixed"].values()))["per_action"])
    for a in actions:
        cells = [f"{r['mixed'][m]['per_action'][a]['detected']} / {r['mixed'][m]['per_action'][a]['correct']} of "
                 f"{r['mixed'][m]['per_action'][a]['n']}" for m in r["mixed"]]
        lines.append(f"| {a} | " + " | ".join(cells) + " |")
    lines += ["", "## Cost", "", "| mode | replay time per frame (us, whole hot path incl. Python) | decision latency "
              "median / p99 (us, reported events) |", "|---|---|---|"]
    for mode in r["mixed"]:
        lat = r["mixed"][mode]["latency"]
        lat_txt = f"{lat['median_us']:.0f} / {lat['p99_us']:.0f}" if lat else "-"
        lines.append(f"| {mode} | {r['replay_us_per_frame'][mode]:.1f} | {lat_txt} |")
    d = r["models"]["dormant"]
    lines += ["", "## Models", "",
              f"- paper (4 classes): {r['models']['paper']['n_cases']} trigger-cut cases "
              f"({r['models']['paper']['n_untriggered']} trials never triggered), SVM {r['models']['paper']['best_params']}.",
              f"- dormant (5 classes {d['classes']}): {d['n_cases']} windows, per class {d['per_class']}, "
              f"per origin {d['per_origin']}, SVM {d['best_params']}.",
              "", "Both exported as one ONNX graph each (`dormant-model/paper.onnx`, `dormant-model/dormant.onnx`, "
              "not committed: `handover dormant` rewrites them).", ""]
    for title, name in r.get("figures", {}).items():
        lines += [f"## {title}", "", f"![{title}]({name})", ""]
    return "\n".join(lines)


def write_figures(out: Path, ev: dict, models: dict) -> dict[str, str]:
    from trainer import dormant_plots

    return {
        "Timeline of the mixed stream (synthetic)": dormant_plots.timeline(
            out / "dormant_timeline.png", ev["_mixed"], ev["_truths"], ev["_decisions"], models["continuous"].meta.pads),
        "False events per hour vs detection delay (synthetic)": dormant_plots.tradeoff(
            out / "dormant_tradeoff.png", ev["idle"], ev["mixed"]),
        "False events by idle source (synthetic)": dormant_plots.false_by_source(
            out / "dormant_sources.png", ev["idle"], ev["idle_hours_by_source"]),
    }
