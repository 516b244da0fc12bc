"""``handover bench inference``: single-case inference, the exported ONNX graph against the
scikit-learn pipeline, same process.

Without ``--model`` it trains a small model on the simulated protocol (synthetic data, seed 0).
Both paths get the same float32 window ``[1, T, C]`` (one case, as the daemon classifies it);
the graph through runtime.model.LoadedModel.run (one intra-op thread, no spinning, input
check included), scikit-learn through BowSVC.predict + decision_function (what the graph
returns). ``--repeats`` (default 5000) graph calls. Writes results/inference.json and .md.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from trainer.measure import command_line, load_average, machine_info, time_calls, write_results

REPEATS, QUICK_REPEATS = 5000, 200


def trained_model(tmp: Path) -> Path:
    import joblib

    from firmware_io.sim import simulate_protocol
    from trainer.dataset import build_dataset
    from trainer.defaults import paper_classifier
    from trainer.trained_file import export_trained

    ds = build_dataset(simulate_protocol(seed=0, n_subjects=2), T=15, pads="distal")
    model = paper_classifier(ds.pad_sizes, per_pad=True, C=100.0, gamma="scale").fit(ds.X, ds.y)
    src = tmp / "bench.joblib"
    joblib.dump({"model": model, "metadata": {"pads": list(ds.pads), "pad_sizes": list(ds.pad_sizes),
                 "training": {"data_fingerprint": ds.fingerprint, **ds.counts().to_meta()}}}, src)
    return export_trained(src, tmp / "bench.onnx")


def _stats(us: np.ndarray) -> dict:
    return {"median": float(np.median(us)), "p99": float(np.percentile(us, 99)), "n": len(us)}


def run(args) -> dict:
    from runtime.model import load_model
    from trainer.verify import load_reference

    repeats = args.repeats or (QUICK_REPEATS if args.quick else REPEATS)
    load_before = load_average()
    with tempfile.TemporaryDirectory() as tmp:
        if not args.model:
            args.say("inference: training a small BoW model on the simulated protocol (synthetic) ...")
        path = Path(args.model) if args.model else trained_model(Path(tmp))
        graph = load_model(path)
        sk = load_reference(path, graph.meta.extra)
        rng = np.random.default_rng(0)
        T, C = graph.meta.T, graph.meta.n_channels
        x = (np.clip(2000 + np.cumsum(rng.normal(0, 80, (1, T, C)), axis=1), 0, 4095) * (rng.random(C) < 0.5)).round()
        x = x.astype(np.float32)
        xs = np.ascontiguousarray(x.transpose(0, 2, 1))

        def run_sklearn():
            sk.predict(xs)
            sk.decision_function(xs)

        args.say(f"inference: {repeats} graph calls, {max(200, repeats // 20)} scikit-learn calls ...")
        onnx_us = time_calls(lambda: graph.run(x), repeats, warmup=50)
        sk_us = time_calls(run_sklearn, max(200, repeats // 20), warmup=50)
        result = {
            "model": str(path.name), "model_id": graph.model_id, "n_nodes": graph.n_nodes, "T": T, "C": C,
            "K": graph.meta.K, "W": graph.meta.W, "n_support_vectors": graph.meta.extra.get("svm", {}).get("n_support_vectors"),
            "onnx_us": _stats(onnx_us), "sklearn_us": _stats(sk_us),
            "machine": machine_info(), "load_before": load_before, "load_after": load_average(),
            "command": command_line("inference", args),
            "note": "model trained on the simulated protocol (synthetic data)" if not args.model else "",
        }
    result["speedup_median"] = result["sklearn_us"]["median"] / result["onnx_us"]["median"]
    result["speedup_p99"] = result["sklearn_us"]["p99"] / result["onnx_us"]["p99"]
    lines = [
        "# Single-case inference: ONNX graph vs scikit-learn (same process)",
        "",
        f"Model: {result['model']} (id {result['model_id']}, {result['n_nodes']} nodes, T={T}, C={C}, "
        f"K={result['K']}, W={result['W']}, {result['n_support_vectors']} support vectors). {result['note']}",
        "",
        "| path | median (µs) | p99 (µs) | runs |",
        "|---|---|---|---|",
        f"| ONNX graph (LoadedModel.run, 1 thread, no spinning) | {result['onnx_us']['median']:.1f} | "
        f"{result['onnx_us']['p99']:.1f} | {result['onnx_us']['n']} |",
        f"| scikit-learn BowSVC (predict + decision_function) | {result['sklearn_us']['median']:.1f} | "
        f"{result['sklearn_us']['p99']:.1f} | {result['sklearn_us']['n']} |",
        "",
        f"Speed-up: {result['speedup_median']:.1f}x at the median, {result['speedup_p99']:.1f}x at p99.",
    ]
    write_results(args.out, "inference", result, lines)
    return result
