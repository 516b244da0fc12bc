"""``handover inspect MODEL [--json]``: a model card from an ONNX model's metadata.

Loads the file through the contract (so a card is only printed for a valid model) and says
what it detects, for which pads, with which T/W/K, trained on what, how accurate, and how big
the graph is. Needs onnxruntime only.
"""

from __future__ import annotations

import argparse
import json

from firmware_io.commands.options import add_json
from runtime.event_rate import rate_text
from runtime.training_counts import TrainingCounts
from runtime.trigger_settings import window_start_text

__all__ = ["add_arguments", "main"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", help="model file (.onnx)")
    add_json(parser, "the card")


def card(model) -> dict:
    from runtime.model import optional_table
    from runtime.model_meta import real_false_events
    from runtime.stream_settings import cost_lines, describe, served_settings

    meta = model.meta
    kernel = meta.extra.get("kernel")
    svm = dict(optional_table(meta.extra.get("svm")))
    features = optional_table(meta.extra.get("features"))
    families = features.get("families")
    if kernel != "rbf":
        svm.pop("gamma", None)  # only the RBF kernel has one
    groups = meta.extra.get("feature_groups")
    return {
        "path": str(model.path),
        "model_id": model.model_id,
        "detects": list(meta.classes),
        "dormant_class": meta.dormant_class,
        "stream_settings": served_settings(meta.dormant_class, meta.trigger),
        "stream_settings_text": describe(meta.dormant_class, meta.trigger, meta.training.get("dormant_cut")),
        "real_false_events": real_false_events(meta),
        "stream_setting_warnings": cost_lines(meta),
        "pads": list(meta.pads),
        "pad_sizes": list(meta.pad_sizes),
        "n_channels": meta.n_channels,
        "T": meta.T,
        "W": meta.W,
        "K": meta.K,
        "per_pad": None if groups is None else len(groups) > 1,
        "level_features": any(v is True for v in (features.get("level_features"), meta.training.get("level_features"))),
        "families": [str(f) for f in families] if isinstance(families, list) else None,
        "feature_weighting": str(features["feature_weighting"]) if features.get("feature_weighting") else None,
        "window_seconds": round(meta.T / meta.sample_rate_hz, 4),
        "sample_rate_hz": meta.sample_rate_hz,
        "trigger": meta.trigger,
        "fullscale": meta.fullscale,
        "score": meta.score,
        "training": meta.training,
        "evaluation": meta.evaluation,
        "kernel": kernel,
        "svm": svm or None,
        "graph": {**optional_table(meta.extra.get("graph")), "n_nodes": model.n_nodes, "n_bytes": model.n_bytes},
        "reference": meta.extra.get("reference"),
        "early": model.early.to_meta() if getattr(model, "early", None) is not None else None,
        "early_disabled": getattr(model, "early_note", None),
    }


def _value(key: str, v) -> str:
    """Rounded for people: accuracies as percentages, other floats to 4 significant digits."""
    if isinstance(v, bool) or v is None:
        return str(v)
    if isinstance(v, float):
        if any(w in key for w in ("accuracy", "per_subject", "at_bound")) or key.endswith("_std"):
            return f"{100 * v:.1f} %"
        return str(int(v)) if v.is_integer() and abs(v) < 1e9 else f"{v:.4g}"
    if isinstance(v, dict):
        return ", ".join(f"{k} {_value(key, x)}" for k, x in v.items())
    return str(v)


def _pad_name(pads: list[int]) -> str:
    from firmware_io.layout import SensorLayout

    name = SensorLayout.sdh2().selection_name(pads)
    return f" = {name}" if name else ""


def _features(c: dict) -> str:
    if c.get("families"):  # trainer.feature_svc: feature families per pad, not one codebook
        weighting = f", weighted '{c['feature_weighting']}'" if c.get("feature_weighting") else ""
        return f"  features: {' + '.join(c['families'])}, per pad ({len(c['pads'])} pads), standardised{weighting}"
    hist = {None: "", True: f", one histogram per pad ({len(c['pads'])})", False: ", one histogram over all pads"}
    level = ", plus each pad's mean level and slope" if c.get("level_features") else ""
    return f"  features: {c['K']} words of W={c['W']} derivative steps{hist[c['per_pad']]}{level}"


def feature_summary(model) -> str:
    """``features: ...`` as the card says it: the families a model has, or its codebook's K and W
    (only the BoW family has them); ``handover export`` prints the same line."""
    return _features(card(model)).strip()


def _svm(c: dict) -> str:
    svm = c["svm"] or {}
    parts = [f"{k} {_value(k, v)}" for k, v in svm.items() if k != "n_support_vectors"]
    if "n_support_vectors" in svm:
        parts.append(f"{svm['n_support_vectors']} support vectors")
    return f"  SVM: {c['kernel']} kernel" + (f", {', '.join(parts)}" if parts else "")


SHOWN_TRAINING = ("n_trials", "n_cases", "n_untriggered", "dormant_windows", "prior_windows", "prior_dormant_windows",
                  "level_features", "data_fingerprint", "date", "project_version", "C", "gamma")
"""Training keys the card shows in its own words (C and gamma are on the SVM line)."""
JSON_ONLY = ("data_folder", "dormant_cut", "hard_margin", "support_vectors_at_bound", "config1_split", "synthetic")
"""Keys a lab engineer does not need on the card's text (``--json`` has every key)."""


def _training_extra(tr: dict) -> str:
    """The training keys beyond the counts, in words where they have some."""
    words = {"data": lambda v: str(v), "seed": lambda v: f"seed {v}",
             "idle_seconds": lambda v: f"{float(v) / 60:.1f} min of recorded idle",
             "prior": lambda v: f"the product's prior at weight {_value('weight', v.get('weight'))}"
             if isinstance(v, dict) else f"prior: {v}"}
    parts = [words[k](v) if k in words else f"{k}: {_value(k, v)}" for k, v in tr.items()
             if k not in SHOWN_TRAINING and k not in JSON_ONLY]
    return "".join(f", {p}" for p in parts) + ("; synthetic data" if tr.get("synthetic") else "")


def _accuracy(ev: dict) -> str:
    """How the trainer scored the model, in words where the key is the trainer's own."""
    if not ev:
        return "not recorded"
    words = {"loso_accuracy": "leave one subject out", "baseline_loso_accuracy": "hand-designed baseline (same folds)",
             "config1_accuracy_mean": "pooled 80/20 split"}
    parts = []
    first = ("loso_accuracy", "loso_per_subject", "config1_accuracy_mean", "baseline_loso_accuracy")
    for k, v in sorted(ev.items(), key=lambda kv: first.index(kv[0]) if kv[0] in first else len(first)):
        if k in JSON_ONLY or k == "config1_accuracy_std":
            continue
        if k == "loso_per_subject":
            parts.append(f"per subject {_value(k, v)}")
        elif k == "config1_accuracy_mean" and ev.get("config1_accuracy_std") is not None:
            parts.append(f"{words[k]} {_value(k, v)} +/- {_value('config1_accuracy_std', ev['config1_accuracy_std'])}")
        else:
            parts.append(f"{words.get(k, k)} {_value(k, v)}")
    return "; ".join(parts) + ("; synthetic data" if ev.get("synthetic") else "")


def _trigger(trig: dict, fullscale: float) -> str:
    """The trigger that cut the training windows, as the daemon will serve it (no kind = threshold)."""
    if trig.get("kind", "threshold") == "onset":
        return (f"onset trigger (a pad departing by {100 * float(trig.get('change', 0)):.0f} % from the settled "
                f"grasp, settled for {float(trig.get('settle_s', 0)):g} s; {window_start_text(trig)})")
    return (f"threshold trigger at {100 * float(trig.get('fraction', 0)):.0f} % of {fullscale:g}"
            + (f", hysteresis {100 * float(trig['hysteresis']):.0f} %" if "hysteresis" in trig else ""))


def _text(c: dict) -> str:
    tr, ev = c["training"], c["evaluation"]
    trig = c["trigger"]
    lines = [
        f"model {c['path']} (id {c['model_id']})",
        f"  detects: {', '.join(c['detects'])}" + (f" (dormant class: {c['dormant_class']})" if c["dormant_class"] else ""),
        f"  stream settings: {c['stream_settings_text']}",
        *(f"  real idle: {k} false events {rate_text(v['events'], v['hours'], 2)}: {v['data']}"
          for k, v in c["real_false_events"].items()),
        *(f"  warning: {line}" for line in c["stream_setting_warnings"]),
        f"  pads: {','.join(str(p) for p in c['pads'])}{_pad_name(c['pads'])} ({c['n_channels']} taxels: "
        f"{', '.join(str(s) for s in c['pad_sizes'])}); serves with scene.pads = \"model\" or this selection",
        f"  window: T={c['T']} frames ({c['window_seconds']:.2f} s at {c['sample_rate_hz']:.2f} Hz), "
        + _trigger(trig, c["fullscale"]),
        _features(c),
        _svm(c),
        f"  trained on: {TrainingCounts.from_meta(tr).text()}, data {str(tr.get('data_fingerprint'))[:16]}, "
        f"{tr.get('date')}, project {tr.get('project_version')}" + _training_extra(tr),
        f"  accuracy: {_accuracy(ev)}",
        f"  graph: {c['graph']['n_nodes']} nodes, {c['graph']['n_bytes']} bytes, opset {c['graph'].get('opset')}",
    ]
    if c.get("early"):
        e = c["early"]
        rule = ("never before T" if e["threshold"] > 1 else f"when the calibrated confidence reaches {e['threshold']:g}"
                + (" and the head agrees with the previous one" if e["agree"] else ""))
        lines.insert(4, f"  early heads: at {', '.join(map(str, e['points']))} frames, reported {rule} (docs/EARLY.md)")
    if c.get("early_disabled"):
        lines.insert(4, f"  warning: {c['early_disabled']}")
    return "\n".join(lines)


def main(args: argparse.Namespace) -> int:
    from runtime.model import load_model
    from runtime.output_check import DEFAULT_BUDGET_FRACTION

    # the daemon's warm-up: realistic windows, the output contract, the default time budget; a missing,
    # unreadable or broken file is a ModelContractError, the user's to fix (handover's one line, exit 2)
    model = load_model(args.model, decision_budget=DEFAULT_BUDGET_FRACTION)
    c = card(model)
    print(json.dumps(c, indent=2, default=str) if args.json else _text(c))
    return 0
