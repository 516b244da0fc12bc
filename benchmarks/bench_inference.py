"""Single-case inference: the exported ONNX graph against the scikit-learn pipeline, same process.

    .venv/bin/python benchmarks/bench_inference.py [--model model.onnx] [--repeats 5000]

Without --model it trains a small model on the simulated protocol (synthetic data, seed 0).
Both paths get the same float32 window ``[1, T, C]`` (one case, as the daemon classifies it);
the graph through runtime.model.LoadedModel.run (one intra-op thread, no spinning, input
check included), scikit-learn through BowSVC.predict + decision_function (what the graph
returns). Writes results/inference.json and results/inference.md.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def timings(fn, repeats: int, warmup: int = 50) -> np.ndarray:
    for _ in range(warmup):
        fn()
    out = np.empty(repeats)
    for i in range(repeats):
        t0 = time.perf_counter_ns()
        fn()
        out[i] = time.perf_counter_ns() - t0
    return out / 1000.0  # microseconds


def machine() -> dict:
    import onnxruntime
    import sklearn

    cpu = "unknown"
    with contextlib.suppress(OSError, StopIteration):
        lines = Path("/proc/cpuinfo").read_text().splitlines()
        cpu = next(line.split(":", 1)[1].strip() for line in lines if line.startswith("model name"))
    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform(),
            "onnxruntime": onnxruntime.__version__, "scikit-learn": sklearn.__version__, "numpy": np.__version__,
            "load_average": os.getloadavg()}


def trained_model(tmp: Path) -> Path:
    import joblib

    from firmware_io.sim import simulate_protocol
    from trainer.classifier import BowSVC
    from trainer.dataset import build_dataset
    from trainer.export_cli import export_trained

    ds = build_dataset(simulate_protocol(seed=0, n_subjects=2), T=15, pads="distal")
    model = BowSVC(kernel="rbf", C=100.0, gamma="scale", per_pad=True, pad_sizes=ds.pad_sizes).fit(ds.X, ds.y)
    src = tmp / "bench.joblib"
    joblib.dump({"model": model, "metadata": {"pads": list(ds.pads), "pad_sizes": list(ds.pad_sizes),
                 "training": {"data_fingerprint": ds.fingerprint, "n_trials": len(ds.y)}}}, src)
    return export_trained(src, tmp / "bench.onnx")


def main() -> int:
    import tempfile

    from runtime.model import load_model
    from trainer.verify import load_reference

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", help="exported .onnx with its .joblib next to it")
    parser.add_argument("--repeats", type=int, default=5000)
    parser.add_argument("--out", default=str(ROOT / "results"))
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
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

        onnx_us = timings(lambda: graph.run(x), args.repeats)
        sk_us = timings(run_sklearn, max(200, args.repeats // 20))
        result = {
            "model": str(path.name), "model_id": graph.model_id, "n_nodes": graph.n_nodes, "T": T, "C": C,
            "K": graph.meta.K, "W": graph.meta.W, "n_support_vectors": graph.meta.extra.get("svm", {}).get("n_support_vectors"),
            "onnx_us": {"median": float(np.median(onnx_us)), "p99": float(np.percentile(onnx_us, 99)), "n": len(onnx_us)},
            "sklearn_us": {"median": float(np.median(sk_us)), "p99": float(np.percentile(sk_us, 99)), "n": len(sk_us)},
            "machine": machine(),
            "command": "python benchmarks/bench_inference.py" + (f" --model {args.model}" if args.model else ""),
            "note": "model trained on the simulated protocol (synthetic data)" if not args.model else "",
        }
    result["speedup_median"] = result["sklearn_us"]["median"] / result["onnx_us"]["median"]
    result["speedup_p99"] = result["sklearn_us"]["p99"] / result["onnx_us"]["p99"]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "inference.json").write_text(json.dumps(result, indent=2) + "\n")
    m = result["machine"]
    md = [
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
        "",
        f"Machine: {m['cpu']}, {m['cores']} cores (shared; load average {m['load_average']}), Python {m['python']}, "
        f"onnxruntime {m['onnxruntime']}, scikit-learn {m['scikit-learn']}, numpy {m['numpy']}.",
        "",
        f"Reproduce: `{result['command']}`",
        "",
    ]
    (out / "inference.md").write_text("\n".join(md))
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    sys.exit(main())
