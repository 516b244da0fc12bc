"""How many later hold windows should the stream model train on? Chosen on validation streams only.

The stream model (``trainer.dormant.fit_stream_model``) serves two settings: ``onset_dormant`` (the
default) and ``continuous``. Continuous mode missed holds: the grip ramps for 0.5-0.9 s and the
model read the ramp's windows, which training never labelled, as dormant. Each variant of
``trainer.dormant.RAMP_WINDOWS`` trains the model on the streams bench's training data (synthetic,
training seed) and is scored on the bench's validation data (validation seed; the test streams are
never generated here):

- ``continuous``: the report rule chosen by the bench's own grid and criterion
  (``benchmarks.streams_rule.choose_rule``: 200 events + 0.25 h idle), its utility;
- ``onset_dormant``: the bench's validation mixed stream (60 events) and idle stream (0.25 h), plus
  the real validation recordings (every other file of ../shared/data; every event there is false).

Criterion, fixed before the run: the sum of the two settings' utilities (right first reports -
wrong first reports - duplicates - false events); ties: fewer extra windows. Writes
results/ramp_windows.{json,md}.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

VARIANTS = ((0, 0), (1, 12), (2, 10), (2, 16), (3, 16), (2, 24), (3, 24))
"""(n, last) of RAMP_WINDOWS["hold"]; (0, 0): no later windows (the model before)."""
CRITERION = ("sum of validation utilities (right first reports - wrong first reports - duplicates - false events) "
             "of continuous (rule chosen by the streams bench's grid on 200 events + 0.25 h idle) and onset_dormant "
             "(60 events + 0.25 h idle + the real validation recordings); ties: fewer extra windows")


def score_variant(variant: tuple[int, int], seed: int, work: str) -> dict:
    """Train the stream model with ``variant`` and score it on the validation data (seed + VAL_OFFSET)."""
    from benchmarks.streams import PART_S, SIZES, VAL_OFFSET
    from benchmarks.streams_rule import choose_rule
    from firmware_io.sim import demo_script, simulate_protocol
    from firmware_io.sim.constants import FRAME_PERIOD_S
    from firmware_io.sim.idle import simulate_idle, simulate_mixed
    from runtime.model import load_model
    from trainer import dormant
    from trainer import streams_eval as se
    from trainer.shared_data import default_data_dir, real_files

    s = SIZES["full"]
    n, last = variant
    dormant.RAMP_WINDOWS = {"hold": (n, last)} if n else {}
    t0 = time.perf_counter()
    path = dormant.fit_stream_model(simulate_protocol(seed=seed, runs=s["runs"]), seed, s["train_idle_min"],
                                    s["train_sessions"], Path(work) / f"ramp_{n}_{last}.onnx")
    model = load_model(path)
    val = seed + VAL_OFFSET
    n_parts = max(1, round(3600.0 * s["val_idle_h"] / PART_S))
    idle = [simulate_idle(3600.0 * s["val_idle_h"] / n_parts, seed=val, part=p) for p in range(n_parts)]
    rule = choose_rule(model, val, idle, lambda _: None)
    best = rule["best"][0]
    mixed = simulate_mixed(demo_script(s["val_events"], seed=val, gap=(10.0, 20.0)), seed=val)
    sm = se.score(se.replay(mixed, model, "onset_dormant"), se.truths_of(mixed), mixed.n_frames, FRAME_PERIOD_S)
    idle_false = sum(len(se.replay(rec, model, "onset_dormant")) for rec in idle)
    real_false = 0
    root = default_data_dir()
    if root.is_dir():
        from firmware_io.recordings.importers import import_any

        for k, (file, _, _) in enumerate(real_files(root)):
            if k % 2:
                continue  # the real test half stays unseen, as in the bench
            try:
                real_false += len(se.replay(import_any(file), model, "onset_dormant"))
            except ValueError:
                continue  # the bench lists the files it cannot replay
    onset_utility = sm["correct"] - sm["wrong_class"] - sm["duplicates"] - sm["false_events"] - idle_false - real_false
    return {"n": n, "last": last, "seconds": round(time.perf_counter() - t0, 1),
            "continuous": {k: best[k] for k in ("correct", "wrong", "missed", "duplicates", "false_events",
                                                "hold_recall", "delay_median_frames", "utility")} | {
                "rule": rule["chosen"]},
            "onset_dormant": {"correct": sm["correct"], "wrong": sm["wrong_class"], "duplicates": sm["duplicates"],
                              "false_mixed": sm["false_events"], "false_idle": idle_false, "false_real": real_false,
                              "hold_correct": sm["per_action"].get("hold", {}).get("correct"),
                              "delay_median_frames": (sm["delay_frames"] or {}).get("median"),
                              "utility": onset_utility},
            "utility": best["utility"] + onset_utility}


def markdown(result: dict) -> str:
    rows = ["| hold windows (n, last frame) | continuous: right / wrong / false, hold recall | continuous utility "
            "| onset_dormant: right / wrong / false (mixed, idle, real) | onset_dormant utility | sum |",
            "|---|---|---|---|---|---|"]
    for r in result["variants"]:
        c, o = r["continuous"], r["onset_dormant"]
        mark = " **chosen**" if (r["n"], r["last"]) == tuple(result["chosen"]) else ""
        rows.append(f"| {r['n']}, {r['last']}{mark} | {c['correct']} / {c['wrong']} / {c['false_events']}, "
                    f"{c['hold_recall']:.2f} | {c['utility']} | {o['correct']} / {o['wrong']} / "
                    f"{o['false_mixed']}, {o['false_idle']}, {o['false_real']} | {o['utility']} | {r['utility']} |")
    return "\n".join([
        "# The stream model's ramp windows (synthetic validation streams + real validation recordings)", "",
        f"Command: `{result['command']}` ({result['seconds']:.0f} s, {result['machine']}).", "",
        __doc__.split("\n\n", 1)[1].strip(), "",
        f"Criterion: {CRITERION}.", "", *rows, "",
        f"Chosen: RAMP_WINDOWS = {{'hold': ({result['chosen'][0]}, {result['chosen'][1]})}} "
        "(trainer/dormant.py ships it). The test streams' figures are in results/streams.md.", ""])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="./dev bench ramp_windows", description=__doc__.split("\n", 1)[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("results"))
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args(argv)
    from trainer.measure import machine_info

    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="ramp-windows-") as work, ProcessPoolExecutor(args.jobs) as pool:
        variants = list(pool.map(score_variant, VARIANTS, [args.seed] * len(VARIANTS), [work] * len(VARIANTS)))
    best = max(variants, key=lambda r: (r["utility"], -r["n"]))
    info = machine_info()
    result = {"command": f"./dev bench ramp_windows --seed {args.seed}", "criterion": CRITERION,
              "seconds": time.perf_counter() - t0, "machine": f"{info.get('cpu', '?')}, {info.get('cores', '?')} cores",
              "variants": variants, "chosen": [best["n"], best["last"]]}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "ramp_windows.json").write_text(json.dumps(result, indent=1) + "\n")
    (args.out / "ramp_windows.md").write_text(markdown(result))
    print(f"chosen: hold {best['n']} windows up to {best['last']} frames after the onset (sum of utilities "
          f"{best['utility']}); wrote {args.out}/ramp_windows.md")
    return 0
