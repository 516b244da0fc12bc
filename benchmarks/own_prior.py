"""``./dev bench own_prior``: what a lab gets from ``handover train`` with the product's prior (synthetic).

Does what a lab does, with the product's commands in this process: ``handover record`` of three scripted
subjects (``subject://?seed=S&speed=max``, the default idle), ``handover train`` (with the prior, and for
lab B also ``--no-prior``), then ``handover demo --model THAT --speed max --json`` on the demo's session
(lab B's session for lab B's recordings); and the demo's simulator-trained model on lab B's session.
Every model is also replayed on 21 demo sessions (benchmarks/session_spread.py), lab B's own models also with the
robot's grasp messages, and the demo's model on both labs' sessions: one session is one draw.
Nothing here chooses anything: the prior's weight and the early rule are chosen inside ``handover train``
on the recordings' cross-validation (trainer/prior.py), never on the demo's session (the test).
Writes results/own_prior.{json,md}.
"""

from __future__ import annotations

import contextlib
import io
import json
import tempfile
import time
from pathlib import Path

from benchmarks.session_spread import SEEDS, SPREAD_HEADER, spread, spread_row
from runtime.event_rate import rate_text
from trainer.early_report import who_comes_early
from trainer.measure import command_line, load_average, machine_info, write_results

NAME = "own_prior"
CASES = [
    # (name, lab, subject seeds, runs, also --no-prior): fixed before the run
    ("default 3x3 seeds 1-3", None, (1, 2, 3), 3, False),
    ("default 3x3 seeds 20-22", None, (20, 21, 22), 3, False),
    ("default 3x3 seeds 30-32", None, (30, 31, 32), 3, False),
    ("lab B 3x1 seeds 1-3", "B", (1, 2, 3), 1, True),
    ("lab B 3x3 seeds 1-3", "B", (1, 2, 3), 3, True),
]
"""The seed sets of the default simulator are the issue's (#37: 1-3 the README's step, 20-22 and 30-32)."""
QUICK = [("quick default 3x1 seeds 1-3", None, (1, 2, 3), 1, True)]
TARGETS = {"default 3x3": "every seed set >= 38/40 right, median onset to report <= 7 frames",
           "lab B 3x1": ">= 38/40 right, 0 outside any event, median <= 7 frames, p90 <= 12",
           "lab B 3x3": ">= 39/40 right"}


def _handover(argv: list[str]) -> tuple[int, str]:
    from runtime.cli import main as handover

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = handover(argv)
    return code, buf.getvalue()


def record(folder: Path, lab: str | None, seeds, runs: int, say, idle_min: float | None = None) -> list[str]:
    """README step 2's ``handover record`` of each scripted subject ``s<seed>`` into ``folder``; their names."""
    for seed in seeds:
        say(f"recording subject://?seed={seed}{'&lab=' + lab if lab else ''} x {runs} run(s) (synthetic) ...")
        device = f"subject://?seed={seed}&speed=max" + (f"&lab={lab}" if lab else "")
        idle = [] if idle_min is None else ["--idle-minutes", str(idle_min)]
        code, _ = _handover(["record", "--device", device, "--subject", f"s{seed}", "--out", str(folder), "--runs",
                             str(runs), "--auto", "--gap", "0", "--countdown", "0", "--quiet", "--no-look", *idle])
        if code != 0:
            raise RuntimeError(f"handover record of {device} failed (exit {code})")
    return [f"s{seed}" for seed in seeds]


def demo(model: Path | None, lab: str | None, work: Path) -> dict:
    """``handover demo --speed max --json`` (with ``--model``, else the demo's own model) on ``lab``'s session."""
    argv = ["demo", "--speed", "max", "--json", "--quiet", "--out", str(work / "demo")]
    argv += ["--model", str(model)] if model else []
    argv += ["--lab", lab] if lab else []
    code, text = _handover(argv)
    if code != 0:
        raise RuntimeError(f"handover {' '.join(argv)} failed (exit {code})")
    d = json.loads(text)  # with --json stdout is the summary alone
    return {k: d.get(k) for k in ("events_expected", "events_correct", "events_missed", "false_events",
                                  "repeat_events", "report_minus_onset_frames", "wrong_events", "missed_events")}


def train(data: Path, out: Path, prior: bool) -> dict:
    code, _ = _handover(["train", "--data", str(data), "--out", str(out), "--no-sweep", "--repeats", "2", "--quiet",
                         "--no-real-idle", *([] if prior else ["--no-prior"])])
    if code != 0:
        raise RuntimeError(f"handover train --data {data} failed (exit {code})")
    m = json.loads((out / "metrics.json").read_text())
    e = m.get("early") or {}
    r = m.get("own_replay") or {}
    return {"seconds": m.get("seconds"), "loso_accuracy": m.get("loso_accuracy"), "prior": m.get("prior"),
            "n_trials": m.get("n_trials"), "dormant_windows": (m.get("idle") or {}).get("dormant_windows"),
            "early_rule": {k: v for k, v in (e.get("rule") or {}).items() if k != "calibration"} or None,
            "early_reported_at": (e.get("operating_point") or {}).get("reported_at"),
            "replay": {k: r.get(k) for k in ("events", "right", "wrong", "missed", "onset_to_report_frames",
                                             "idle_hours", "false_events", "false_per_hour", "with_arm_messages",
                                             "early_heads")}}


def run_case(case, work: Path, say) -> dict:
    name, lab, seeds, runs, no_prior = case
    t0 = time.perf_counter()
    data = work / "data"
    record(data, lab, seeds, runs, say)
    row: dict = {"name": name, "lab": lab or "A (default)", "subjects": list(seeds), "runs": runs}
    for prior in (True, False) if no_prior else (True,):
        key = "prior" if prior else "no_prior"
        say(f"own_prior: {name}: handover train{'' if prior else ' --no-prior'} ...")
        row[key] = train(data, work / key, prior)
        row[key]["demo"] = demo(work / key / "model.onnx", lab, work)
        say(f"own_prior: {name} ({key}): replaying {len(SEEDS)} demo sessions ...")
        row[key]["spread"] = spread(work / key / "model.onnx", lab)
        if lab and prior:
            row[key]["spread_robot"] = spread(work / key / "model.onnx", lab, robot=True)
        d = row[key]["demo"]
        say(f"own_prior: {name} ({key}): {d['events_correct']}/{d['events_expected']} right, median "
            f"{(d['report_minus_onset_frames'] or {}).get('median')} frames")
    row["seconds"] = round(time.perf_counter() - t0, 1)
    return row


def run(args) -> dict:
    say = args.say
    load_before = load_average()
    t0 = time.perf_counter()
    rows = []
    demo_model_b, demo_spread = None, []
    def written(done: bool) -> dict:  # after every case: a run stopped late keeps what it measured
        out = {"synthetic": True, "complete": done, "cases": rows, "demo_model_on_lab_b": demo_model_b,
               "demo_model_spread": demo_spread,
               "targets": TARGETS, "machine": machine_info(), "command": command_line(NAME, args),
               "load_before": load_before, "load_after": load_average(), "seconds": round(time.perf_counter() - t0, 1)}
        write_results(args.out, NAME, out, markdown(out))
        return out

    with tempfile.TemporaryDirectory(prefix="handover-own-prior-") as tmp:
        for k, case in enumerate(QUICK if args.quick else CASES):
            rows.append(run_case(case, Path(tmp) / f"case{k}", say))
            written(False)
        if not args.quick:
            say("own_prior: the demo's simulator-trained model on lab B's session ...")
            demo_model_b = demo(None, "B", Path(tmp))
            demo_spread = [spread(Path(tmp) / "demo" / "report" / "stream-model.onnx", lab) for lab in (None, "B")]
    return written(True)


def _demo_cells(d: dict | None) -> str:
    if not d:
        return "- | - | - | -"
    f = d.get("report_minus_onset_frames") or {}
    med, p90 = f.get("median"), f.get("p90")
    return (f"{d['events_correct']}/{d['events_expected']} | {d['false_events']} | "
            f"{'-' if med is None else f'{med:.0f}'} | {'-' if p90 is None else f'{p90:.0f}'}")


def markdown(r: dict) -> list[str]:
    lines = ["# A lab's own model with the product's prior (**synthetic**)", "",
             f"Command: `{r['command']}`; {r['seconds']:.0f} s on {r['machine'].get('cpu', '?')} "
             f"(load before {r['load_before']}, after {r['load_after']}). Each row: `handover record --device "
             "\"subject://?seed=S&speed=max[&lab=B]\" --runs R --auto --gap 0 --countdown 0` for three subjects (the "
             "default idle), `handover train --no-sweep --repeats 2 --no-real-idle [--no-prior]`, then `handover "
             "demo --model THAT --speed max --json [--lab B]` (the demo's 40 scripted events by unseen simulated "
             "subjects; lab B's hand and people for lab B). The prior's weight and the early rule were chosen inside "
             "`handover train` by cross-validation on the recordings, never on the demo's session.", "",
             "| recording | training | demo right | outside any event | onset to report median (frames) | p90 | "
             "prior weight | LOSO (lab cases) | early rule | held-out replay: right | idle false events |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in r["cases"]:
        for key in ("prior", "no_prior"):
            t = row.get(key)
            if not t:
                continue
            p = t.get("prior") or {}
            rule = t.get("early_rule") or {}
            rep = t.get("replay") or {}
            loso = t["loso_accuracy"]
            lines.append(f"| {row['name']} | {'prior + own' if key == 'prior' else 'own only (--no-prior)'} | "
                         f"{_demo_cells(t['demo'])} | {p.get('weight', '-')} | "
                         f"{'-' if loso is None else f'{loso:.1%}'} | "
                         f"{rule.get('threshold', '-')} ({who_comes_early(rule)}) | {rep.get('right')}/{rep.get('events')} | "
                         f"{rate_text(rep.get('false_events') or 0, rep.get('idle_hours'))} |")
    if r.get("demo_model_on_lab_b"):
        lines.append(f"| lab B session | the demo's simulator-trained model | {_demo_cells(r['demo_model_on_lab_b'])} "
                     "| - | - | - | - | - |")
    lines += ["", "Targets (issue #37): " + "; ".join(f"{k}: {v}" for k, v in r["targets"].items()) + "."
              + ("" if r.get("complete") else " **Partial: the run stopped before every row was measured.**"), ""]
    return lines + spread_lines(r)


def spread_lines(r: dict) -> list[str]:
    """The same models over many demo sessions: how much of a row above is its session."""
    from firmware_io.sim.session import HELD_OUT_SEED_OFFSET

    lines = [f"## The same models over {len(SEEDS)} demo sessions (**synthetic**)", "",
             f"The sessions of `handover demo --seed S` for S = {SEEDS[0]}, {SEEDS[1]}-{SEEDS[-1]} (the emulator's session "
             f"S + {HELD_OUT_SEED_OFFSET}, by people none of the recordings above hold; 0 is the demo's; 1 and 2 are left out: the "
             "trigger's settings were chosen on them), each replayed in process through the daemon's code in the "
             "model's setting (benchmarks/session_spread.py); `handover demo --model M --seed S [--lab B]` plays one "
             "of them. A session's p90 is interpolated between its events' whole frames, so it may have a decimal; "
             "p90 <= 12 is lab B's target, shown for every row. Missed: events with no report at all (the trigger "
             "did not fire, or the model read the window as dormant). 'Robot says grasp closed': the robot's `grasp closed` / `grasp "
             "open` messages (docs/GUIDE.md), which arm the trigger at once instead of waiting for the grasp to settle "
             "(the simulated robot says it 0.6 s after first contact, trainer/streams_eval.py's robot_messages; in every "
             "session here that is before the person acts).",
             "", *SPREAD_HEADER]
    for row in r["cases"]:
        for key, what in (("prior", "prior + own"), ("no_prior", "own only")):
            t = row.get(key) or {}
            for skey in ("spread", "spread_robot"):
                if t.get(skey):
                    lines.append(spread_row(f"{row['name']}, {what}", t[skey]))
    for s in r.get("demo_model_spread") or []:
        lines.append(spread_row("the demo's simulator-trained model", s))
    return [*lines, ""]
