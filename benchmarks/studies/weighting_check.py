"""Does reweighing the default's standardised features help, by the default rule's own measure?

Hypothesis (issue 12, real_slip): after one StandardScaler the family with more features dominates
the RBF distance. This counts the features per family on every real task (on the first outer
training part), then scores FeatureSVC's ``feature_weighting`` rules (``trainer.feature_weighting``)
exactly as ``trainer.default_choice`` scores candidates: grouped 3-fold inside the outer training
parts of every real task (the outer test folds never enter), ranked with every candidate of
``handover train --select`` by the rule (latency: CPU p99 of the exported graph on the simulated
protocol; the nested simulated leave-one-subject-out as the gate). Seeds 1 and 2 of the inner split
show how much of a gap is the split's own noise; they are not part of the rule.

Writes results/weighting_check.{json,md} and a dated section of results/slip_diagnosis.md.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from trainer.defaults import default_candidate_name

WEIGHTED = "hand+stats rbf distinct"
"""The candidate of ``trainer.select.CANDIDATES`` this check is about."""
VARIANTS = (("hand+stats rbf block_count", ("hand", "stats"), "rbf", {"feature_weighting": "block_count"}),
            ("hand+stats rbf block_mfa", ("hand", "stats"), "rbf", {"feature_weighting": "block_mfa"}))
"""The two multi-block scalings of the hypothesis, scored but not candidates."""
NOISE_SEEDS = (1, 2)
NOISE_ROWS = tuple(dict.fromkeys(("hand+stats rbf", WEIGHTED, default_candidate_name(), "stats rbf", "rocket+stats linear",
                                  *(v[0] for v in VARIANTS))))
SECTION_END = "<!-- /weighting_check -->"
SECTION_START = "<!-- weighting_check: ./dev bench weighting_check writes this section; " \
                "./dev bench slip_diagnosis keeps it -->"


def family_sizes(task) -> dict:
    """Features per family (all, and varying on the first outer training part) and how many features
    the ``distinct`` rule finds duplicated there."""
    from trainer.feature_svc import FeatureSVC
    from trainer.feature_weighting import distinct_weights

    tr = np.asarray(task.splits[0].train)
    model = FeatureSVC(families=("hand", "stats"), pad_sizes=task.pad_sizes, pad_shapes=task.pad_shapes,
                       C=1.0, gamma="scale").fit(task.X[tr], task.y[tr])
    hist = model.transform_histograms(task.X[tr])
    out, start = {"pads": len(task.pad_sizes)}, 0
    for name, block in model.blocks_:
        part = hist[:, start : start + block.n_features_out_]
        out[name] = {"features": int(block.n_features_out_), "varying": int(np.count_nonzero(part.std(axis=0) > 0))}
        start += block.n_features_out_
    out["duplicated"] = int(np.count_nonzero(distinct_weights(model.scaler_.transform(hist)) < 1))
    return out


def run(data_dir: Path, n_jobs: int, say) -> dict:
    from benchmarks.compare import machine_info
    from trainer.dataset import build_dataset
    from trainer.default_choice import apply_rule, inner_real_score, inner_sim_score
    from trainer.measure import simulated_protocol
    from trainer.real_tasks import T, real_tasks
    from trainer.select import CANDIDATES

    t0 = time.perf_counter()
    load_before = [round(v, 2) for v in os.getloadavg()]
    tasks, notes = real_tasks(data_dir)
    if not tasks:
        raise FileNotFoundError(f"no real tasks under {data_dir}: {notes}")
    candidates = (*CANDIDATES, *VARIANTS)
    sizes = {t.name: family_sizes(t) for t in tasks}
    ds = build_dataset(list(simulated_protocol(seed=0)), T=T, pads="all")
    latency = _latencies(candidates, ds)
    rows = {}
    for name, *_ in candidates:
        per_task = {t.name: inner_real_score(name, t, n_jobs, 0, candidates) for t in tasks}
        rows[name] = {"real_inner": per_task, "real_score": float(np.mean(list(per_task.values()))), **latency[name]}
        say(f"  {name}: {rows[name]['real_score']:.4f}")
    chosen, order = apply_rule(rows, lambda n: inner_sim_score(n, ds, n_jobs, 0, candidates), say)
    noise = {seed: {name: float(np.mean([inner_real_score(name, t, n_jobs, seed, candidates) for t in tasks]))
                    for name in NOISE_ROWS} for seed in NOISE_SEEDS}
    return {"tasks": [t.name for t in tasks], "family_sizes": sizes, "rows": rows, "order": order, "chosen": chosen,
            "candidates": [c[0] for c in CANDIDATES], "noise_seeds": noise, "date": time.strftime("%Y-%m-%d"),
            "seconds": round(time.perf_counter() - t0, 1), "machine": machine_info(), "load_before": load_before,
            "load_after": [round(v, 2) for v in os.getloadavg()], "n_simulated_cases": len(ds.y)}


def _latencies(candidates, ds) -> dict:
    """CPU p50/p99 (us) of each candidate's exported graph, fitted on the simulated protocol."""
    from threadpoolctl import threadpool_limits

    from trainer.default_choice import candidate_estimator
    from trainer.select import graph_latency

    shapes = [(ds.layout.matrices[p].cells_y, ds.layout.matrices[p].cells_x) for p in ds.pads]
    out = {}
    with tempfile.TemporaryDirectory(prefix="handover-weighting-") as tmp, threadpool_limits(1):
        for name, *_ in candidates:
            est = candidate_estimator(name, ds.pad_sizes, shapes, 0, candidates)
            stats = graph_latency(est.fit(ds.X, ds.y), ds, Path(tmp), name, 0)
            out[name] = {"p50_us": stats["p50"], "p99_us": stats["p99"]}
    return out


def markdown(res: dict) -> list[str]:
    """The section for results/slip_diagnosis.md (also the whole of results/weighting_check.md)."""
    tasks, rows = res["tasks"], res["rows"]
    lines = [f"## Feature weighting, by the rule's inner measure ({res['date']})", "",
             "Hypothesis: after one StandardScaler the family with more features dominates the RBF distance. "
             "Features per family (first outer training part; varying = not constant there; duplicated = "
             "features the `distinct` rule finds to be the same quantity, |r| >= 1 - 1e-6):", "",
             "| task | pads | hand (varying) | stats (varying) | duplicated |", "|---|---|---|---|---|"]
    for name in tasks:
        s = res["family_sizes"][name]
        lines.append(f"| {name} | {s['pads']} | {s['hand']['features']} ({s['hand']['varying']}) | "
                     f"{s['stats']['features']} ({s['stats']['varying']}) | {s['duplicated']} |")
    lines += ["", "Per pad the hand family has 14 features and the stats family 13: the blocks are about equal, so "
              "scaling each block to equal weight (`block_count`: by its feature count; `block_mfa`: by its first "
              "eigenvalue, as Multiple Factor Analysis does) hardly changes the distance. What does double-count is "
              "three quantities per pad that both families compute (the hand family's pad maximum, pad mean and mean "
              "derivative are constant multiples of the stats family's peak, mean pressure and pressure change): "
              "`distinct` counts each such quantity once (other duplicates above are pads whose features coincide "
              "on that training part)."]
    lines += ["", "Inner score (nested grouped 3-fold inside every outer training part, as trainer/default_choice.py; "
              "mean accuracy %), in the rule's order; rows not in `handover train --select` are marked:", "",
              "| candidate | rank | mean | " + " | ".join(tasks) + " | p99 us (CPU) | sim inner LOSO |",
              "|---|---|---|" + "---|" * len(tasks) + "---|---|"]
    for name in sorted(rows, key=lambda n: res["order"].index(n) if n in res["order"] else len(rows)):
        r = rows[name]
        rank = res["order"].index(name) + 1 if name in res["order"] else "-"
        mark = "" if name in res["candidates"] else " (not a candidate)"
        sim = f"{100 * r['sim_inner']:.1f}" if "sim_inner" in r else "-"
        lines.append(f"| {name}{mark} | {rank} | {100 * r['real_score']:.1f} | "
                     + " | ".join(f"{100 * r['real_inner'][t]:.1f}" for t in tasks) + f" | {r['p99_us']:.0f} | {sim} |")
    lines += ["", "Same mean, other seeds of the inner split (noise check, not part of the rule): "
              + "; ".join(f"seed {seed}: " + ", ".join(f"{n} {100 * v:.1f}" for n, v in by.items())
                          for seed, by in res["noise_seeds"].items()) + ".", "",
              f"Verdict by the rule: **{res['chosen']}** is first"
              + (" (the shipped default's candidate)." if res["chosen"] == default_candidate_name() else
                 " (not what trainer/defaults.py ships; a full `./dev bench compare` would confirm)."), *_margin(res)]
    return lines


def _margin(res: dict) -> list[str]:
    """How far the first is ahead of the second, at the rule's seed and at the noise seeds."""
    first, second = (res["order"] + [None, None])[:2]
    if second is None:
        return []
    gaps = [100 * (by[first] - by[second]) for by in res["noise_seeds"].values() if first in by and second in by]
    return ["", f"Margin of {first} over {second}: {100 * (res['rows'][first]['real_score'] - res['rows'][second]['real_score']):+.2f} "
            "points at the rule's seed" + (", " + ", ".join(f"{g:+.2f}" for g in gaps) + " at the noise seeds"
                                          if gaps else "") + "."]


def upsert_section(md_path: Path, lines: list[str]) -> None:
    """Put ``lines`` between this check's markers at the end of ``md_path`` (replacing an older section)."""
    text = md_path.read_text() if md_path.exists() else ""
    kept = text.split(SECTION_START)[0].rstrip("\n")
    md_path.write_text(kept + "\n\n" + "\n".join([SECTION_START, *lines, SECTION_END]) + "\n")


def kept_section(md_path: Path) -> list[str]:
    """This check's section of ``md_path`` (empty if none), for a writer that rewrites the file."""
    text = md_path.read_text() if md_path.exists() else ""
    if SECTION_START not in text:
        return []
    return text.split(SECTION_START)[1].split(SECTION_END)[0].strip("\n").splitlines()


def main(argv: list[str] | None = None) -> int:
    from trainer.measure import write_results
    from trainer.shared_data import default_data_dir

    parser = argparse.ArgumentParser(prog="./dev bench weighting_check", description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="results")
    parser.add_argument("--data", help="shared data folder holding sdh2-dsa/ (default ../shared/data)")
    parser.add_argument("--n-jobs", type=int, default=2)
    parser.add_argument("--rewrite", action="store_true", help="only rewrite the markdown from OUT/weighting_check.json")
    args = parser.parse_args(argv)
    try:
        if args.rewrite:
            res = json.loads((Path(args.out) / "weighting_check.json").read_text())
        else:
            res = run(Path(args.data) if args.data else default_data_dir(), args.n_jobs,
                      lambda t: print(t, file=sys.stderr, flush=True))
    except (OSError, ValueError) as exc:
        print(f"weighting_check: {exc}", file=sys.stderr)
        return 2
    if not args.rewrite:
        res["command"] = shlex.join(["./dev", "bench", "weighting_check", "--out", args.out]
                                    + (["--data", args.data] if args.data else []))
    lines = markdown(res)
    write_results(args.out, "weighting_check", res, ["# Feature weighting check (issue 12)", "", *lines[2:], "",
                                                      f"Ran in {res['seconds']:.0f} s."])
    upsert_section(Path(args.out) / "slip_diagnosis.md", [*lines, "", f"Reproduce: `{res['command']}` "
                   f"({res['seconds']:.0f} s; details in results/weighting_check.md)."])
    return 0
