"""``./dev bench streams_own``: the model a lab trains from its own recordings, measured on live streams.

1. three scripted simulated subjects (``subject://``, synthetic, their own seeds) are recorded with
   ``handover record`` (a short protocol: every pose, object and action, ``runs`` runs, plus the
   default idle stretches);
2. the cut of dormant windows (``trainer.recorded_idle.DORMANT_CUTS``) is chosen by ``CRITERION``
   on validation streams (seed + 2): each cut's models (these subjects, and lab B's) replayed through the daemon;
3. ``handover train`` on the recordings (the product path, with the cut in code) exports the model;
   its held-out replay is taken from the training metrics;
4. that model on the test streams of ``./dev bench streams`` (seed + 1: the same synthetic idle
   stream the demo model's 20 false events per hour come from; a mixed stream), on the demo's
   scripted session, and on every real SDH-2 recording in ../shared/data (none holds a handover).

Writes results/streams_own.json/.md and its headline keys into results/streams.json (``OWN_KEYS``;
``./dev bench streams`` carries them over when it rewrites that file).
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

from benchmarks.own_prior import record
from firmware_io.sim.constants import FRAME_PERIOD_S
from trainer import streams_eval as se
from trainer.early import rule_in_words
from trainer.measure import command_line, load_average, machine_info, write_results
from trainer.own_replay import model_stream_mode

NAME = "streams_own"
SUBJECT_SEEDS = (10, 11, 12)
"""Seeds of the recorded scripted subjects: other people than the simulated protocol's training
subjects (seed 0), the streams' subjects (seeds 1, 2) and the demo's (seed 1000)."""
LAB_B_SEEDS = (1, 2, 3)
"""Lab B's subjects for choosing the cut (own_prior's lab B recipe: a hand and people the prior does not know)."""
SIZES = {
    "full": {"runs": 3, "idle_min": None, "val_events": 120, "val_idle_h": 0.25, "test_events": 100,
             "test_idle_h": 1.0},
    "quick": {"runs": 1, "idle_min": 1.3, "val_events": 12, "val_idle_h": 0.05, "test_events": 12,
              "test_idle_h": 0.05},
}
"""``idle_min`` None: the recorder's default."""
CRITERION = ("utility = right first reports - wrong first reports - repeats - reports outside any event on a "
             "validation session (demo_script(val_events, seed + 2), synthetic) played by each simulated lab, each "
             "scored with that lab's own model (lab A: the subjects below; lab B: subject://?seed=1, 2, 3&lab=B, 1 run each), trained "
             "with the cut the way handover train trains (prior, early rule) - false events of lab A's model on "
             "the validation idle stream (seed + 2; the idle simulator has lab A's hand only); every bad report "
             "costs what a good one gains (the streams bench's rule); ties: the cut in code")
OWN_KEYS = ("own_model_idle_false_events_per_hour", "own_model_idle_false_events_per_hour_arm_messages",
            "own_model_idle_false_events_per_hour_full_window", "own_model_arm_move_false_events_per_hour",
            "own_model_arm_move_false_events_per_hour_arm_messages",
            "own_model_demo_events_correct_fraction", "own_model_demo_events_outside",
            "own_model_real_idle_false_events_per_hour", "own_model_dormant_cut",
            "own_model_real_idle_trained_false_events_per_hour")
"""The headline keys this bench writes into results/streams.json too."""


def cut_models(folder: Path, work: Path, seed: int, say) -> dict:
    """One loaded model per dormant cut, each trained as ``handover train --dormant-cut CUT`` trains it (the
    product's prior and early rule included)."""
    from runtime.model import load_model
    from trainer.pipeline import train
    from trainer.recorded_idle import DORMANT_CUTS
    from trainer.train_options import TrainOptions

    out = {}
    for cut in DORMANT_CUTS:
        say(f"streams_own: handover train --dormant-cut {cut} on {folder.name} ...")
        report = work / f"cut-{folder.name}-{cut}"
        train(TrainOptions(data=str(folder), out=str(report), no_sweep=True, repeats=2, quiet=True, seed=seed,
                           replay=False, real_idle=False, dormant_cut=cut))
        out[cut] = load_model(report / "model.onnx", warm_up=False)
    return out


def validation(models: dict, seed: int, s: dict, say) -> dict:
    """Each cut's models (``models[lab][cut]``) on their lab's validation session, lab A's also on the validation
    idle stream (the idle simulator has one hand); the utility of ``CRITERION``, summed over the labs."""
    from firmware_io.sim import demo_script, simulate_session
    from firmware_io.sim.idle import simulate_idle
    from firmware_io.sim.lab import get_lab

    say(f"streams_own: validation sessions ({s['val_events']} events per lab) and idle stream (synthetic, seed {seed}) ...")
    idle = simulate_idle(3600.0 * s["val_idle_h"], seed=seed, part=0)
    names = se.source_names(idle, idle.n_frames)
    out: dict = {}
    for lab, by_cut in models.items():
        script = demo_script(s["val_events"], seed=seed, objects=get_lab(lab).objects)
        session = simulate_session(script, seed=seed, lab=lab)
        for cut, model in by_cut.items():
            mode = model_stream_mode(model)
            o = se.session_outcomes(se.replay(session, model, mode), session.trials)
            i = se.score(se.replay(idle, model, mode), [], idle.n_frames, FRAME_PERIOD_S, names) if lab == "A" else None
            wrong = o["detected"] - o["correct"]
            false = i["false_events"] if i else 0
            row = {"mode": mode, "session": {k: o[k] for k in ("expected", "correct", "missed", "outside", "repeats")},
                   "session_wrong": wrong, "idle_false_events": i["false_events"] if i else None,
                   "idle_hours": i["idle_hours"] if i else None,
                   "utility": o["correct"] - wrong - o["repeats"] - o["outside"] - false}
            v = out.setdefault(cut, {"labs": {}, "utility": 0})
            v["labs"][lab] = row
            v["utility"] += row["utility"]
    return out


def choose(val: dict) -> str:
    from trainer.recorded_idle import DORMANT_CUT

    return max(val, key=lambda cut: (val[cut]["utility"], cut == DORMANT_CUT))


def test_streams(model, seed: int, s: dict, say) -> dict:
    """The streams bench's test idle stream (parts of its length, its seed) and a mixed stream."""
    from benchmarks.streams import PART_S
    from firmware_io.sim import demo_script
    from firmware_io.sim.idle import simulate_idle, simulate_mixed

    mode = model_stream_mode(model)
    n_parts = max(1, round(3600.0 * s["test_idle_h"] / PART_S))
    plain, arm, full, hours = [], [], [], []
    for p in range(n_parts):
        say(f"streams_own: test idle stream part {p + 1}/{n_parts} (synthetic, seed {seed}) ...")
        rec = simulate_idle(3600.0 * s["test_idle_h"] / n_parts, seed=seed, part=p)
        hours.append(se.source_hours([rec], FRAME_PERIOD_S))
        names = se.source_names(rec, rec.n_frames)
        plain.append(se.score(se.replay(rec, model, mode), [], rec.n_frames, FRAME_PERIOD_S, names))
        arm.append(se.score(se.replay(rec, model, f"{mode}_arm"), [], rec.n_frames, FRAME_PERIOD_S, names))
        if getattr(model, "early", None) is not None:  # the same model answering only at the full window
            full.append(se.score(se.replay(rec, model, mode, scene={"early_events": []}), [], rec.n_frames,
                                 FRAME_PERIOD_S, names))
    say(f"streams_own: test mixed stream, {s['test_events']} events ...")
    mixed = simulate_mixed(demo_script(s["test_events"], seed=seed, gap=(10.0, 20.0)), seed=seed)
    m = se.score(se.replay(mixed, model, mode), se.truths_of(mixed), mixed.n_frames, FRAME_PERIOD_S,
                 se.source_names(mixed, mixed.n_frames))
    source_h = se.sum_counts(hours)
    return {"mode": mode, "idle_source_hours": source_h, "idle": with_arm_move_rate(se.merge_idle(plain), source_h),
            "idle_arm_messages": with_arm_move_rate(se.merge_idle(arm), source_h),
            "idle_full_window": with_arm_move_rate(se.merge_idle(full), source_h) if full else None,
            "mixed": {k: m[k] for k in ("n_events", "correct", "wrong_class", "missed", "duplicates", "false_events",
                                        "correct_rate", "delay_frames", "false_by_source")}}


def with_arm_move_rate(idle: dict, source_h: dict) -> dict:
    """``idle`` with its false events per hour of the stream's arm moves (``arm_move_false_per_hour``)."""
    arm_h = source_h.get("arm_move", 0.0)
    return {**idle, "arm_move_hours": arm_h,
            "arm_move_false_per_hour": idle["false_by_source"].get("arm_move", 0) / arm_h if arm_h else None}


def demo_session(model, seed: int) -> dict:
    from trainer.commands.demo_cli import scripted_session

    mode = model_stream_mode(model)
    session_seed, _, session = scripted_session(seed)
    o = se.session_outcomes(se.replay(session, model, mode), session.trials)
    return {"mode": mode, "seed": session_seed, **{k: o[k] for k in (
        "expected", "detected", "correct", "missed", "outside", "repeats", "correct_fraction", "missed_events",
        "wrong_events")}}


def run(args) -> dict:
    from benchmarks.streams import TEST_OFFSET, VAL_OFFSET
    from runtime.model import load_model
    from trainer.own_replay import real_idle
    from trainer.pipeline import train
    from trainer.recorded_idle import DORMANT_CUT
    from trainer.shared_data import default_data_dir
    from trainer.train_options import TrainOptions

    say = args.say
    s = SIZES["quick" if args.quick else "full"]
    load_before = load_average()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="handover-streams-own-") as tmp:
        work = Path(tmp)
        data = work / "data"
        subjects = record(data, None, SUBJECT_SEEDS, s["runs"], say, s["idle_min"])
        lab_b = work / "lab_b"
        record(lab_b, "B", LAB_B_SEEDS, 1, say, s["idle_min"])
        models = {"A": cut_models(data, work, args.seed, say), "B": cut_models(lab_b, work, args.seed, say)}
        val = validation(models, args.seed + VAL_OFFSET, s, say)
        chosen = choose(val)
        say(f"streams_own: chosen dormant cut on validation: {chosen} (in code: {DORMANT_CUT})")
        say("streams_own: handover train on the recordings ...")
        result = train(TrainOptions(data=str(data), out=str(work / "report"), no_sweep=True, repeats=2, quiet=True,
                                    seed=args.seed))
        model = load_model(work / "report" / "model.onnx", warm_up=False)
        metrics = result.metrics
        test = test_streams(model, args.seed + TEST_OFFSET, s, say)
        demo = demo_session(model, args.seed)
        real = real_idle(model, default_data_dir(), say)  # trainer.own_replay: the one way real idle is scored
        from benchmarks.streams_own_real import on_half, run_real

        lab = run_real(data, work, subjects, args.seed, args.quick, say)
    out = {
        "own_model_idle_false_events_per_hour": test["idle"]["false_per_hour"],
        "own_model_idle_false_events_per_hour_arm_messages": test["idle_arm_messages"]["false_per_hour"],
        "own_model_idle_false_events_per_hour_full_window": (test["idle_full_window"] or {}).get("false_per_hour"),
        "own_model_arm_move_false_events_per_hour": test["idle"]["arm_move_false_per_hour"],
        "own_model_arm_move_false_events_per_hour_arm_messages": test["idle_arm_messages"]["arm_move_false_per_hour"],
        "own_model_demo_events_correct_fraction": demo["correct_fraction"],
        "own_model_demo_events_outside": demo["outside"],
        "own_model_real_idle_false_events_per_hour": real["false_per_hour"] if real else None,
        "own_model_dormant_cut": DORMANT_CUT,
        "own_model_real_idle_trained_false_events_per_hour":
            ((lab or {}).get("held_out", {}).get("onset_dormant") or {}).get("false_per_hour"),
        "real_idle_lab": lab, "synthetic_idle_model_on_held_out_half": on_half(real, lab),
        "demo_model_on_held_out_half": _streams_key(args.out, "real_test_half_false_events_per_hour"),
        "dormant_cut_chosen": chosen,
        "criterion": CRITERION,
        "subjects": [f"subject://?seed={k}" for k in SUBJECT_SEEDS],
        "sizes": s, "seed": args.seed,
        "model": {"classes": list(model.meta.classes), "dormant_class": model.meta.dormant_class,
                  "families": metrics.get("families"), "n_trials": metrics["n_trials"], "idle": metrics.get("idle"),
                  "loso_accuracy": metrics.get("loso_accuracy"),
                  "early_rule": {k: v for k, v in ((metrics.get("early") or {}).get("rule") or {}).items()
                                 if k != "calibration"} or None},
        "early_rule_criterion": rule_in_words(),
        "held_out_replay": metrics.get("own_replay"),
        "validation": val, "test": test, "demo": demo, "real": real,
        "demo_model_idle_false_events_per_hour": _demo_model_figure(args.out),
        "synthetic_streams": True, "machine": machine_info(), "command": command_line(NAME, args),
        "load_before": load_before, "load_after": load_average(), "seconds": round(time.perf_counter() - t0, 1),
    }
    from benchmarks.streams_own_report import markdown

    write_results(args.out, NAME, out, markdown(out))
    carry_into_streams(Path(args.out), out)
    return out


def _streams_key(out: str, key: str):
    """A headline figure of results/streams.json (the streams bench), or None."""
    try:
        return json.loads((Path(out) / "streams.json").read_text())[key]
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _demo_model_figure(out: str) -> float | None:
    """The demo model's false events per hour on the same test idle stream (results/streams.json)."""
    try:
        return float(json.loads((Path(out) / "streams.json").read_text())["test"]["onset_dormant"]["idle"]
                     ["false_per_hour"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def carry_into_streams(out: Path, own: dict) -> None:
    """Write ``OWN_KEYS`` into ``out/streams.json`` when it exists (the streams bench's headline file)."""
    path = out / "streams.json"
    if not path.is_file():
        return
    data = json.loads(path.read_text())
    data.update({k: own.get(k) for k in OWN_KEYS})
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(data, indent=2) + "\n")
    tmp.replace(path)


def own_keys(out: str | Path) -> dict:
    """``OWN_KEYS`` from ``out/streams_own.json`` (for the streams bench to carry over), or none."""
    try:
        own = json.loads((Path(out) / f"{NAME}.json").read_text())
    except (OSError, ValueError):
        return {}
    return {k: own.get(k) for k in OWN_KEYS}
