"""``./dev bench field``: learning from the working day, end to end on the emulator (synthetic).

A day compressed into minutes, every step a product command in its own process:

1. the lab's data: the simulated protocol of three subjects and an idle stream (synthetic); ``handover
   train`` gives the serving model A (with the dormant class) and a candidate B (``--no-dormant``);
2. day 1: ``handover emulate`` plays a scripted session (unseen simulated subjects) to ``handover run``
   serving A, B in ``[model] shadow``, ``[capture] folder`` on; a robot that knows the truth (the
   emulator's ``--script-out``) says ``outcome <true class>`` after each event (benchmarks/field_run.py);
3. ``handover review field/ --accept-outcomes``, then ``handover train --data lab/ --data field/``: C;
4. day 2 (another session): A serving, C in shadow (capture on); then C is promoted (docs/GUIDE.md: touch,
   then one move into the model folder) and day 2 is played again to C.

Written to results/field.{json,md}: the shadow's agreement (health view), what C in shadow predicted
against what C did once promoted on the same session, events captured against events decided, bytes
per hour of capture. Models are trained with ``--early off`` (minutes, not the question here).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

from benchmarks.field_run import Day, run_day
from trainer.measure import command_line, load_average, machine_info, write_results

NAME = "field"
SIZES = {
    "full": {"runs": 2, "idle_s": 1200.0, "day1_events": 160, "day2_events": 110, "gap": (6.0, 14.0), "speed": 16.0},
    "quick": {"runs": 1, "idle_s": 600.0, "day1_events": 40, "day2_events": 20, "gap": (6.0, 14.0), "speed": 16.0},
}
IDLE_EVERY_S = 60.0
"""``[capture] idle_every_s`` of the bench: a compressed day needs more than the default's one per 10 min."""
DAY1_SEED, DAY2_SEED = 2001, 3001
"""Session seeds: simulated subjects the lab's protocol (seed 0) never had."""
TRAIN = ["--no-sweep", "--no-replay", "--repeats", "2", "--early", "off", "--quiet"]


def handover(*argv: str) -> str:
    """A product command in this process; its stdout, RuntimeError on a non-zero exit."""
    from runtime.cli import main

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main([str(a) for a in argv])
    if code != 0:
        raise RuntimeError(f"handover {' '.join(map(str, argv))}: exit {code}")
    return out.getvalue()


def lab_data(folder: Path, s: dict, seed: int) -> None:
    """The simulated protocol of three subjects and an idle stream (synthetic)."""
    from firmware_io.sim import simulate_protocol
    from firmware_io.sim.idle import simulate_idle

    folder.mkdir(parents=True, exist_ok=True)
    for rec in simulate_protocol(seed=seed, n_subjects=3, runs=s["runs"]):
        rec.save(folder / f"subject_{rec.trials[0].subject}.hrec")
    simulate_idle(s["idle_s"], seed=seed).save(folder / "idle.hrec")


def session(path: Path, events: int, seed: int, gap: tuple[float, float]) -> Path:
    from firmware_io.sim import demo_script, simulate_session

    return simulate_session(demo_script(events, seed=seed, gap=gap), seed=seed).save(path)


def drop(model: Path, folder: Path, name: str) -> None:
    """Install a model the documented way: a dot-temp copy in the folder, then a rename."""
    folder.mkdir(parents=True, exist_ok=True)
    tmp = folder / f".{name}.tmp"
    shutil.copyfile(model, tmp)
    os.chmod(tmp, 0o644)
    os.replace(tmp, folder / name)


def first_reports(lines: list[dict], day: Day, reported_only: bool = False) -> tuple[dict[int, str], int]:
    """Per scripted event (index) the first class reported inside its span, and the reports outside any."""
    trials, firsts, outside = day.script.trials, {}, 0
    for line in lines:
        if reported_only and not line.get("reported"):
            continue
        _loop, frame = day.script.frame_of(int(line["device_time_ms"]))
        k = next((i for i, t in enumerate(trials) if t.first <= frame <= t.last), None)
        if k is None:
            outside += 1
        else:
            firsts.setdefault(k, line["class"])
    return firsts, outside


def scored(firsts: dict[int, str], outside: int, day: Day) -> dict:
    """Right, wrong, missed and false events of one model's first reports on a day's session."""
    truth = [t.action for t in day.script.trials]
    right = sum(firsts.get(k) == a for k, a in enumerate(truth))
    return {"events": len(truth), "right": right, "wrong": len(firsts) - right, "missed": len(truth) - len(firsts),
            "false_events": outside, "right_fraction": round(right / len(truth), 4) if truth else None}


def candidate_only(day: Day) -> dict:
    """The candidate's reports where the serving model reported none (the shadow rule counts them against it),
    and how many of them the script says were right."""
    from benchmarks.field_run import truth_of

    only = [x for x in day.of_type("shadow") if x.get("reported") and not x.get("serving_reported")]
    right = sum(truth_of(day.script, int(x["device_time_ms"])) == x["class"] for x in only)
    return {"events": len(only), "right": right}


def capture_figures(folder: Path, day: Day, decided: int) -> dict:
    """What the capture folder holds against what the daemon decided, and its size per hour of stream."""
    from firmware_io.recordings.field_capture import EVENT_PREFIX, IDLE_PREFIX
    from trainer.field_folder import read_events

    files = [p for p in folder.iterdir() if p.is_file()]
    size = sum(p.stat().st_size for p in files)
    events = read_events(folder, lambda _line: None)
    reported = [e for e in events if e.reported]
    idle = [p for p in files if p.name.startswith(IDLE_PREFIX)]
    event_bytes = [p.stat().st_size for p in files if p.name.startswith(EVENT_PREFIX)]
    hours = day.device_s / 3600.0
    return {"events_decided": decided, "events_captured": len(reported), "unreported_windows_captured":
            len(events) - len(reported), "idle_stretches_captured": len(idle), "bytes": size,
            "stream_hours": round(hours, 4), "bytes_per_hour": round(size / hours) if hours else None,
            "bytes_per_event_file": round(sum(event_bytes) / len(event_bytes)) if event_bytes else None,
            "bytes_per_idle_file": round(sum(p.stat().st_size for p in idle) / len(idle)) if idle else None,
            "events_per_hour": round(decided / hours, 1) if hours else None}


def missing_parts() -> list[str]:
    """The daemon's config keys this bench needs that this checkout lacks (#39's shadow and capture)."""
    from runtime.config_keys import KEYS

    have = {k.name for k in KEYS}
    return [k for k in ("model.shadow", "capture.folder", "capture.idle_every_s") if k not in have]


def run(args, keep: Path | None = None) -> dict:
    """The bench (module docstring); ``keep``: work there and keep the folders (to look at a run)."""
    if missing := missing_parts():
        raise RuntimeError(f"the daemon of this checkout has no {', '.join(missing)}: the bench needs them")
    say = args.say
    s = SIZES["quick" if args.quick else "full"]
    load_before, t0 = load_average(), time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="handover-field-") as tmp:
        work = Path(keep or tmp)
        lab, field, field2 = work / "lab", work / "field", work / "field2"
        say("field: the lab's data and models A (serving) and B (candidate, no dormant class) ...")
        lab_data(lab, s, args.seed)
        handover("train", "--data", lab, "--out", work / "A", "--seed", args.seed, *TRAIN)
        handover("train", "--data", lab, "--out", work / "B", "--seed", args.seed, "--no-dormant", *TRAIN)
        models, shadow = work / "models", work / "shadow"
        drop(work / "A" / "model.onnx", models, "a.onnx")
        drop(work / "B" / "model.onnx", shadow, "b.onnx")
        day1_file = session(work / "day1.hrec", s["day1_events"], DAY1_SEED, s["gap"])
        day2_file = session(work / "day2.hrec", s["day2_events"], DAY2_SEED, s["gap"])
        say(f"field: day 1, {s['day1_events']} events at speed {s['speed']:g}: A serving, B in shadow, capture on ...")
        day1 = run_day(work / "run1", day1_file, models, s["speed"], shadow, field, IDLE_EVERY_S, say)
        review = handover("review", field, "--accept-outcomes").strip().replace(str(field), "field/")
        labels = json.loads((field / "labels.json").read_text()) if (field / "labels.json").is_file() else {}
        say(f"field: review: {review}; training C on lab/ + field/ ...")
        handover("train", "--data", lab, "--data", field, "--out", work / "C", "--seed", args.seed, *TRAIN)
        trained = json.loads((work / "C" / "metrics.json").read_text())
        for old in shadow.glob("*.onnx"):
            old.unlink()
        drop(work / "C" / "model.onnx", shadow, "c.onnx")
        say("field: day 2: A serving, C in shadow, capture on ...")
        day2a = run_day(work / "run2", day2_file, models, s["speed"], shadow, field2, IDLE_EVERY_S, say)
        os.utime(shadow / "c.onnx")  # the promotion as docs/GUIDE.md says it: the newest file serves,
        os.replace(shadow / "c.onnx", models / "c.onnx")  # and one move into the model folder
        say("field: day 2 again: C promoted (serving) ...")
        day2b = run_day(work / "run3", day2_file, models, s["speed"], say=say)
        out = results(s, day1, day2a, day2b, capture_figures(field, day1, len(day1.of_type("decision"))),
                      capture_figures(field2, day2a, len(day2a.of_type("decision"))), labels, review, trained)
    out.update(synthetic=True, machine=machine_info(), command=command_line(NAME, args), load_before=load_before,
               load_after=load_average(), seconds=round(time.perf_counter() - t0, 1), sizes=s,
               idle_every_s=IDLE_EVERY_S, seeds={"lab": args.seed, "day1": DAY1_SEED, "day2": DAY2_SEED})
    from benchmarks.field_report import markdown

    write_results(args.out, NAME, out, markdown(out))
    return out


def results(s: dict, day1: Day, day2a: Day, day2b: Day, capture1: dict, capture2: dict, labels: dict, review: str,
            trained: dict) -> dict:
    """The figures of the three runs (module docstring)."""
    from collections import Counter

    a1 = scored(*first_reports(day1.of_type("decision"), day1), day1)
    b1 = scored(*first_reports(day1.of_type("shadow"), day1, reported_only=True), day1)
    a2 = scored(*first_reports(day2a.of_type("decision"), day2a), day2a)
    shadow_c, shadow_out = first_reports(day2a.of_type("shadow"), day2a, reported_only=True)
    promoted_c, promoted_out = first_reports(day2b.of_type("decision"), day2b)
    n = len(day2a.script.trials)
    same = sum(shadow_c.get(k) == promoted_c.get(k) for k in range(n))
    return {
        "day1": {"serving_A": a1, "shadow_B": b1, "shadow_health": day1.health.get("shadow"),
                 "shadow_only_events": candidate_only(day1), "capture": capture1,
                 "outcomes_said": dict(day1.said), "wall_s": day1.wall_s},
        "frames_lost": {name: {k: d.health.get(k) for k in ("frames_received", "frames_dropped", "frames_stale")}
                        for name, d in (("day1", day1), ("day2_shadow", day2a), ("day2_promoted", day2b))},
        "review": {"line": review, "labels": len(labels), "labels_per_class": dict(Counter(labels.values()))},
        "trained_C": {"n_trials": trained.get("n_trials"), "loso_accuracy": trained.get("loso_accuracy"),
                      "idle": trained.get("idle")},
        "day2": {"serving_A": a2, "shadow_C": scored(shadow_c, shadow_out, day2a),
                 "promoted_C": scored(promoted_c, promoted_out, day2b), "shadow_health": day2a.health.get("shadow"),
                 "shadow_only_events": candidate_only(day2a),
                 "capture": capture2, "wall_s": [day2a.wall_s, day2b.wall_s]},
        "shadow_vs_promoted": {"events": n, "same_first_report": same, "share": round(same / n, 4) if n else None,
                               "false_events_shadow": shadow_out, "false_events_promoted": promoted_out},
    }
