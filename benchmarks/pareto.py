"""Error against single-case run time over a grid of K, W, T, kernel, per-pad and pad sets.

Phase 1 (parallel, <= 2 joblib workers): for each grid point, leave-one-subject-out and
configuration-1 error on the simulated protocol (synthetic data), a final fit on all cases and
its ONNX export. Phase 2 (one process, nothing else of ours running): the single-case time of
each exported graph through runtime.model.load_model (1 intra-op thread, spinning off), and of
the reference points: the paper's hand-designed features with an SVM, and aeon's MiniRocket (no
ONNX export exists for it: its Python predict is timed). The graph against the scikit-learn
pipeline of the same model is one question, answered by ``handover bench inference``.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from trainer.defaults import BOW_ALONE_KERNEL, DEFAULT_MODEL
from trainer.measure import (
    export_metadata,
    fmt_us,
    load_average,
    percentiles,
    run_facts,
    simulated_protocol,
    time_calls,
    write_results,
)

NAME = "pareto"

DEFAULT_PARAMS = {"K": DEFAULT_MODEL["K"], "W": DEFAULT_MODEL["W"], "T": DEFAULT_MODEL["T"], "kernel": BOW_ALONE_KERNEL,
                  "pads": DEFAULT_MODEL["pads"], "per_pad": DEFAULT_MODEL["per_pad"]}
"""The BoW family alone with the product default's settings (``handover train --features bow``): the
point the pareto sweep of BoW settings marks. The product default itself is ``trainer.defaults``."""


def grid(quick: bool) -> list[dict]:
    """The points: a K x W x T x kernel core on all pads, then per-pad and distal variants."""
    base = {"per_pad": False, "pads": "all"}
    if quick:
        return [dict(DEFAULT_PARAMS), {"K": 5, "W": 5, "T": 10, "kernel": "linear", "pads": "distal", "per_pad": True}]
    points = []
    for kernel in ("rbf", "linear"):
        for T in (10, 15, 20):
            for W in (5, 7):
                for K in (5, 10, 20):
                    points.append({"K": K, "W": W, "T": T, "kernel": kernel, **base})
    for kernel in ("rbf", "linear"):
        for pads, per_pad in (("all", True), ("distal", False), ("distal", True)):
            for K in (5, 10, 20):
                points.append({"K": K, "W": 7, "T": 15, "kernel": kernel, "pads": pads, "per_pad": per_pad})
    return points


def label(p: dict) -> str:
    return (f"K={p['K']} W={p['W']} T={p['T']} {p['kernel']} {p['pads']}" + (" per-pad" if p["per_pad"] else ""))


def is_default(p: dict) -> bool:
    return all(p.get(k) == v for k, v in DEFAULT_PARAMS.items())


def _evaluate(kind: str, params: dict, X, y, groups, seeds: tuple[int, ...], folder: str, extra: dict) -> dict:
    """One point in a worker: LOSO + config 1 errors, a final fit on all cases (+ ONNX for BoW)."""
    from threadpoolctl import threadpool_limits

    from trainer.evaluation import config1, config2

    est = _estimator(kind, params, extra)
    t0 = time.perf_counter()
    with threadpool_limits(1):
        c2 = config2(est, X, y, groups, n_jobs=1)
        c1 = config1(est, X, y, seeds=seeds, n_jobs=1)
        model = _estimator(kind, params, extra).fit(X, y)
    out = {"kind": kind, "params": params, "loso_error": 1.0 - c2["accuracy"], "loso_subject_std": c2["subject_std"],
           "config1_error": 1.0 - c1["mean"], "config1_std": c1["std"], "model": model,
           "eval_seconds": time.perf_counter() - t0}
    if kind == "bow":
        from trainer.onnx_export import export_onnx

        meta = export_metadata(extra["ds_meta"], model, {"loso_accuracy": c2["accuracy"],
                                                        "config1_accuracy_mean": c1["mean"]})
        out["onnx"] = str(export_onnx(model, Path(folder) / f"{extra['tag']}.onnx", meta))
    return out


def _estimator(kind: str, params: dict, extra: dict):
    if kind == "bow":
        from trainer.defaults import paper_classifier

        return paper_classifier(extra["pad_sizes"], n_words=params["K"], window=params["W"], kernel=params["kernel"],
                                per_pad=params["per_pad"])
    if kind == "baseline":
        from trainer.baseline import BaselineSVC

        return BaselineSVC(pad_shapes=extra["pad_shapes"], kernel="rbf")
    from benchmarks.compare import MiniRocketCases

    return MiniRocketCases(n_kernels=extra["n_kernels"], random_state=0)


class _DatasetMeta:
    """The few Dataset fields export_metadata reads (picklable, without the cases)."""

    def __init__(self, ds) -> None:
        for name in ("pads", "pad_sizes", "fullscale", "fraction", "trigger", "sample_rate_hz", "fingerprint"):
            setattr(self, name, getattr(ds, name))
        self._counts = ds.counts()

    def counts(self):
        return self._counts


def run(args) -> dict:
    from joblib import Parallel, delayed

    from trainer.dataset import build_dataset

    say = args.say
    load_before = load_average()
    t_start = time.perf_counter()
    recordings = list(simulated_protocol(args.seed, args.quick))
    points = grid(args.quick)
    datasets: dict = {}

    def data(T: int, pads: str):
        if (T, pads) not in datasets:
            datasets[(T, pads)] = build_dataset(recordings, T=T, pads=pads)
        return datasets[(T, pads)]

    seeds = (0,) if args.quick else (0, 1)
    notes = []
    with tempfile.TemporaryDirectory(prefix="handover-pareto-") as folder:
        tasks = []
        for i, p in enumerate(points):
            ds = data(p["T"], p["pads"])
            extra = {"pad_sizes": tuple(ds.pad_sizes), "ds_meta": _DatasetMeta(ds), "tag": f"p{i:03d}"}
            tasks.append(delayed(_evaluate)("bow", p, ds.X, ds.y, ds.groups, seeds, folder, extra))
        ref = data(DEFAULT_PARAMS["T"], DEFAULT_PARAMS["pads"])
        shapes = [(ref.layout.matrices[m].cells_y, ref.layout.matrices[m].cells_x) for m in ref.pads]
        ref_params = {"T": DEFAULT_PARAMS["T"], "pads": DEFAULT_PARAMS["pads"]}
        tasks.append(delayed(_evaluate)("baseline", ref_params, ref.X, ref.y, ref.groups, seeds, folder,
                                        {"pad_shapes": shapes}))
        try:
            import aeon  # noqa: F401  (the `bench` extra)

            n_kernels = 840 if args.quick else 10000
            tasks.append(delayed(_evaluate)("minirocket", {**ref_params, "n_kernels": n_kernels}, ref.X, ref.y,
                                            ref.groups, seeds, folder, {"n_kernels": n_kernels}))
        except ImportError:
            notes.append("aeon is not installed (pip install 'tactile-handover[bench]'): MiniRocket left out.")
        say(f"pareto: evaluating {len(tasks)} points on {len(recordings)} simulated subjects (synthetic) with 2 workers ...")
        done = []
        for r in Parallel(n_jobs=2, return_as="generator")(tasks):
            done.append(r)
            say(f"  [{len(done)}/{len(tasks)}] {r['kind']} {label(r['params']) if r['kind'] == 'bow' else ''} "
                f"LOSO error {r['loso_error']:.1%} ({r['eval_seconds']:.0f} s)")
        eval_seconds = time.perf_counter() - t_start
        say("pareto: timing single-case inference (one process, 1 intra-op thread, spinning off) ...")
        rows = _time_all(done, datasets, args)
    front = pareto_front([(r["time_p50_us"], r["loso_error"]) for r in rows])
    for r, on in zip(rows, front, strict=True):
        r["on_front"] = bool(on)
    default = next((r for r in rows if r["kind"] == "bow" and is_default(r["params"])), None)
    result = {
        "synthetic": True,
        "data": f"simulated protocol (synthetic), seed {args.seed}, {len(recordings)} subjects",
        "error": "1 - accuracy; loso = leave one subject out (all held-out predictions pooled); "
                 f"config1 = pooled stratified 80/20, mean over seeds {list(seeds)}; C/gamma searched inside each fit",
        "timing": "single case [1, T, C] float32 from the data set; ONNX via runtime.model.load_model "
                  "(1 intra-op thread, spinning off, input check included); others via their Python predict",
        "rows": rows,
        "default_on_front": bool(default and default["on_front"]),
        "onnx_p50_us": default and default["time_p50_us"],
        "onnx_p99_us": default and default["time_p99_us"],
        "notes": notes,
        "eval_seconds": round(eval_seconds, 1),
        **run_facts(NAME, args, load_before, t_start),
    }
    plot(rows, Path(args.out) / f"{NAME}.png")
    write_results(args.out, NAME, result, markdown(result))
    return result


def rerender(out: str | Path) -> dict:
    """Re-mark the default and rewrite pareto.md/.png from an earlier run's pareto.json: no new measurement
    (for when the default changes to another point of the same grid)."""
    import json

    path = Path(out) / f"{NAME}.json"
    try:
        res = json.loads(path.read_text())
        rows = res["rows"]
    except (OSError, ValueError, KeyError) as exc:
        raise ValueError(f"{path}: no earlier pareto result to re-render ({exc})") from None
    for r in rows:
        r["default"] = r["kind"] == "bow" and is_default(r["params"])
    d = next((r for r in rows if r["default"]), None)
    if d is None:
        raise ValueError(f"{path}: the default {label(DEFAULT_PARAMS)} is not among the measured points")
    res.update(default_on_front=bool(d["on_front"]), onnx_p50_us=d["time_p50_us"], onnx_p99_us=d["time_p99_us"])
    res["notes"].append(f"Re-rendered from this run's measurements (`./dev bench pareto --rerender`), the default "
                        f"being {label(DEFAULT_PARAMS)}; nothing was measured again.")
    plot(rows, Path(out) / f"{NAME}.png")
    write_results(out, NAME, res, markdown(res))
    return res


def _time_all(done: list[dict], datasets: dict, args) -> list[dict]:
    from runtime.model import load_model

    repeats = 30 if args.quick else 2000
    py_repeats = 10 if args.quick else 200
    rows = []
    for r in done:
        p = r["params"]
        ds = datasets[(p["T"], p["pads"])]
        case = ds.X[len(ds.X) // 2]  # [C, T] one real (synthetic) case
        row = {k: v for k, v in r.items() if k not in ("model", "onnx")}
        if r["kind"] == "bow":
            graph = load_model(r["onnx"], intra_op_threads=1, allow_spinning=False)
            x = np.ascontiguousarray(case.T[None], dtype=np.float32)
            t = percentiles(time_calls(lambda g=graph, x=x: g.run(x), repeats))
            row.update(label=label(p), n_nodes=graph.n_nodes, onnx_bytes=graph.n_bytes,
                       n_support_vectors=int(sum(r["model"].svm_.n_support_)), default=is_default(p))
        else:
            xs = case[None]
            t = percentiles(time_calls(lambda m=r["model"], xs=xs: m.predict(xs), py_repeats, warmup=3))
            row.update(label="hand-designed features + SVM (paper's baseline, Python)" if r["kind"] == "baseline"
                       else f"MiniRocket (aeon, {p['n_kernels']} kernels, Python predict)", default=False)
        row.update(time_p50_us=t["p50"], time_p99_us=t["p99"], time_runs=t["n"])
        rows.append(row)
    return rows


def pareto_front(points: list[tuple[float, float]]) -> list[bool]:
    """True where no other point is at least as fast and as accurate and better in one of them."""
    out = []
    for i, (t, e) in enumerate(points):
        dominated = any((t2 <= t and e2 <= e) and (t2 < t or e2 < e) for j, (t2, e2) in enumerate(points) if j != i)
        out.append(not dominated)
    return out


def plot(rows: list[dict], path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(8.5, 5.5))
    styles = {"rbf": ("o", "tab:blue"), "linear": ("s", "tab:green")}
    for kernel, (marker, color) in styles.items():
        pts = [r for r in rows if r["kind"] == "bow" and r["params"]["kernel"] == kernel]
        ax.scatter([r["time_p50_us"] for r in pts], [100 * r["loso_error"] for r in pts], marker=marker,
                   facecolors="none", edgecolors=color, label=f"BoW + SVM ({kernel}), ONNX graph")
    refs = {"baseline": ("^", "tab:red"), "minirocket": ("P", "tab:purple")}
    for kind, (marker, color) in refs.items():
        pts = [r for r in rows if r["kind"] == kind]
        if pts:
            ax.scatter([r["time_p50_us"] for r in pts], [100 * r["loso_error"] for r in pts], marker=marker, s=60,
                       color=color, label=pts[0]["label"])
    front = sorted((r for r in rows if r["on_front"]), key=lambda r: r["time_p50_us"])
    ax.step([r["time_p50_us"] for r in front], [100 * r["loso_error"] for r in front], where="post", color="black",
            lw=1, label="Pareto front")
    for r in rows:
        if r.get("default"):
            ax.scatter([r["time_p50_us"]], [100 * r["loso_error"]], marker="*", s=260, color="gold",
                       edgecolors="black", zorder=5,
                       label=f"default {label(DEFAULT_PARAMS)} ({'on' if r['on_front'] else 'not on'} the front)")
    ax.set_xscale("log")
    ax.set_xlabel("single-case inference time, median (us, log scale)")
    ax.set_ylabel("leave-one-subject-out error (%)")
    ax.set_title("Error against run time (simulated protocol, synthetic data)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def markdown(res: dict) -> list[str]:
    rows = sorted(res["rows"], key=lambda r: r["time_p50_us"])
    d = next((r for r in rows if r.get("default")), None)
    lines = [
        "# Error against run time (simulated protocol, synthetic data)",
        "",
        f"Data: {res['data']}. Error: {res['error']}. Timing: {res['timing']}.",
        "",
        "![error against time](pareto.png)",
        "",
    ]
    if d:
        lines += [
            f"Default model ({label(DEFAULT_PARAMS)}, the BoW family alone, what `handover train --features bow` builds): LOSO error {d['loso_error']:.1%}, "
            f"ONNX median {fmt_us(d['time_p50_us'])} us, p99 {fmt_us(d['time_p99_us'])} us; "
            f"**{'on' if d['on_front'] else 'not on'} the Pareto front**. The graph against the same model's "
            "scikit-learn pipeline: results/inference.md.",
            "",
        ]
        if not d["on_front"]:
            better = [r for r in rows if r["on_front"] and r["kind"] == "bow"
                      and r["time_p50_us"] <= d["time_p50_us"] and r["loso_error"] <= d["loso_error"]]
            if better:
                lines += ["Front points that dominate the default: " + "; ".join(r["label"] for r in better) + ".", ""]
    lines += [
        "| model | LOSO error | config 1 error | median (us) | p99 (us) | SVs | front |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        name = r["label"] + (" **(default)**" if r.get("default") else "")
        lines.append(f"| {name} | {r['loso_error']:.1%} +/- {r['loso_subject_std']:.1%} | "
                     f"{r['config1_error']:.1%} +/- {r['config1_std']:.1%} | {fmt_us(r['time_p50_us'])} | "
                     f"{fmt_us(r['time_p99_us'])} | {r.get('n_support_vectors', '-')} | "
                     f"{'yes' if r['on_front'] else ''} |")
    lines += ["", f"+/- is the std over held-out subjects (LOSO) and over seeds (config 1). {res['note']}"]
    lines += [f"Evaluation took {res['eval_seconds']:.0f} s, the whole run {res['seconds']:.0f} s."]
    lines += [f"Note: {n}" for n in res["notes"]]
    return lines
