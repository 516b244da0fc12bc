"""``handover inspect MODEL [--json]``: a model card from an ONNX model's metadata.

Loads the file through the contract (so a card is only printed for a valid model) and says
what it detects, for which pads, with which T/W/K, trained on what, how accurate, and how big
the graph is. Needs onnxruntime only.
"""

from __future__ import annotations

import argparse
import json
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", help="model file (.onnx)")
    parser.add_argument("--json", action="store_true", help="print the card as JSON")


def card(model) -> dict:
    meta = model.meta
    return {
        "path": str(model.path),
        "model_id": model.model_id,
        "detects": list(meta.classes),
        "dormant_class": meta.dormant_class,
        "pads": list(meta.pads),
        "pad_sizes": list(meta.pad_sizes),
        "n_channels": meta.n_channels,
        "T": meta.T,
        "W": meta.W,
        "K": meta.K,
        "window_seconds": round(meta.T / meta.sample_rate_hz, 4),
        "sample_rate_hz": meta.sample_rate_hz,
        "trigger": meta.trigger,
        "fullscale": meta.fullscale,
        "score": meta.score,
        "training": meta.training,
        "evaluation": meta.evaluation,
        "kernel": meta.extra.get("kernel"),
        "svm": meta.extra.get("svm"),
        "graph": {**meta.extra.get("graph", {}), "n_nodes": model.n_nodes, "n_bytes": model.n_bytes},
        "reference": meta.extra.get("reference"),
    }


def _trials(n) -> str:
    """``36 trials``; a model exported from a bare estimator file does not know its trials."""
    return "an unknown number of trials (not recorded)" if n is None else f"{n} trials"


def _text(c: dict) -> str:
    tr, ev = c["training"], c["evaluation"]
    lines = [
        f"model {c['path']} (id {c['model_id']})",
        f"  detects: {', '.join(c['detects'])}" + (f" (dormant class: {c['dormant_class']})" if c["dormant_class"] else ""),
        f"  pads: {c['pads']} ({c['n_channels']} taxels: {c['pad_sizes']})",
        f"  window: T={c['T']} frames ({c['window_seconds']} s at {c['sample_rate_hz']:g} Hz), "
        f"trigger at {100 * float(c['trigger'].get('fraction', 0)):.0f} % of {c['fullscale']:g}",
        f"  features: {c['K']} words of W={c['W']} derivative steps; SVM kernel {c['kernel']} {c['svm'] or ''}",
        f"  trained on: {_trials(tr.get('n_trials'))}, data {str(tr.get('data_fingerprint'))[:16]}, "
        f"{tr.get('date')}, project {tr.get('project_version')}"
        + "".join(f", {k}: {v}" for k, v in tr.items() if k not in ("n_trials", "data_fingerprint", "date", "project_version")),
        "  accuracy: " + (", ".join(f"{k}: {v}" for k, v in ev.items()) if ev else "not recorded"),
        f"  graph: {c['graph']['n_nodes']} nodes, {c['graph']['n_bytes']} bytes, opset {c['graph'].get('opset')}",
        f"  scores: {c['score']}",
    ]
    return "\n".join(lines)


def main(args: argparse.Namespace) -> int:
    from runtime.model import ModelContractError, load_model
    from runtime.output_check import DEFAULT_BUDGET_FRACTION

    try:
        # the daemon's warm-up: realistic windows, the output contract, the default time budget
        model = load_model(args.model, decision_budget=DEFAULT_BUDGET_FRACTION)
    except ModelContractError as exc:
        print(f"handover inspect: {exc}", file=sys.stderr)
        return 1
    c = card(model)
    print(json.dumps(c, indent=2, default=str) if args.json else _text(c))
    return 0
