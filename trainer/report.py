"""The report folder: figures (small PNGs), ``metrics.json`` and a Markdown page people read.

Every figure and table says whether its numbers come from synthetic (simulated) data and
which split produced them.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

DPI = 80


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _tag(synthetic: bool) -> str:
    return " (synthetic data)" if synthetic else ""


def plot_confusion(cm: Sequence[Sequence[int]], labels: Sequence[str], title: str, path: Path) -> Path:
    plt = _plt()
    cm = np.asarray(cm, dtype=float)
    rows = cm / np.maximum(cm.sum(axis=1, keepdims=True), 1)
    fig, ax = plt.subplots(figsize=(3.8, 3.4), dpi=DPI)
    ax.imshow(rows, cmap="Blues", vmin=0, vmax=1)
    for i in range(len(labels)):
        for j in range(len(labels)):
            ax.text(j, i, f"{int(cm[i, j])}", ha="center", va="center",
                    color="white" if rows[i, j] > 0.6 else "black", fontsize=8)
    ax.set_xticks(range(len(labels)), labels, fontsize=8)
    ax.set_yticks(range(len(labels)), labels, fontsize=8)
    ax.set_xlabel("predicted", fontsize=8)
    ax.set_ylabel("true", fontsize=8)
    ax.set_title(title, fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_sweep(rows: list[dict], param: str, fixed: str, path: Path, synthetic: bool) -> Path:
    """Accuracy against one parameter (one line per kernel)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(3.8, 2.8), dpi=DPI)
    for kernel in sorted({r.get("kernel", "rbf") for r in rows}):
        pts = sorted((r[param], r["accuracy"], r.get("std", 0.0)) for r in rows if r.get("kernel", "rbf") == kernel)
        x, acc, std = (np.array(v) for v in zip(*pts, strict=True))
        ax.errorbar(x, acc * 100, yerr=std * 100, marker="o", ms=3, capsize=2, label=kernel)
    ax.set_xlabel(param, fontsize=8)
    ax.set_ylabel("accuracy %", fontsize=8)
    ax.set_title(f"accuracy vs {param} ({fixed}){_tag(synthetic)}", fontsize=7)
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_tsne(embedding: np.ndarray, y: np.ndarray, path: Path, synthetic: bool) -> Path:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(3.8, 3.4), dpi=DPI)
    for label in sorted(set(y.tolist())):
        pick = y == label
        ax.scatter(embedding[pick, 0], embedding[pick, 1], s=4, label=label, alpha=0.7)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(f"t-SNE of the BoW histograms{_tag(synthetic)}", fontsize=8)
    ax.legend(fontsize=7, markerscale=2)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_baseline_vs_bow(metrics: dict, path: Path, synthetic: bool) -> Path:
    plt = _plt()
    names = ["config 1 (pooled 80/20)", "config 2 (LOSO)"]
    bow = [metrics["config1_accuracy_mean"], metrics["loso_accuracy"]]
    base = [metrics["baseline_config1_accuracy_mean"], metrics["baseline_loso_accuracy"]]
    err_bow = [metrics["config1_accuracy_std"], metrics["loso_subject_std"]]
    err_base = [metrics["baseline_config1_accuracy_std"], metrics["baseline_loso_subject_std"]]
    x = np.arange(2)
    fig, ax = plt.subplots(figsize=(3.8, 2.8), dpi=DPI)
    ax.bar(x - 0.2, np.array(bow) * 100, 0.4, yerr=np.array(err_bow) * 100, capsize=2, label="BoW + SVM")
    ax.bar(x + 0.2, np.array(base) * 100, 0.4, yerr=np.array(err_base) * 100, capsize=2, label="hand features + SVM")
    ax.set_xticks(x, names, fontsize=7)
    ax.set_ylabel("accuracy %", fontsize=8)
    ax.set_ylim(0, 105)
    ax.tick_params(labelsize=7)
    ax.set_title(f"BoW vs hand-designed features{_tag(synthetic)}", fontsize=8)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def _pct(v: float) -> str:
    return f"{100 * v:.1f} %"


def _class_table(per_class: dict) -> list[str]:
    lines = ["| class | precision | recall | support |", "|---|---|---|---|"]
    for c, v in per_class.items():
        lines.append(f"| {c} | {_pct(v['precision'])} | {_pct(v['recall'])} | {v['support']} |")
    return lines


def _margin_lines(margin: dict | None) -> list[str]:
    """The plain statement whether the fitted SVM is the paper's hard margin."""
    if not margin:
        return []
    counts = (f" ({margin['n_at_bound']} of {margin['n_support_vectors']} support vectors at the bound)"
              if margin["hard_margin"] else "")
    return ["", f"SVM margin of the final model (C = {margin['C']:g}): {margin['statement']}{counts}."]


def write_markdown(out: Path, metrics: dict, command: str, figures: dict[str, str]) -> Path:
    """report.md: the command, the data, the two configurations, baseline, sweeps, figures."""
    syn = metrics["synthetic"]
    label = "**synthetic**" if syn else "measured"
    c1, c2 = metrics["config1"], metrics["config2"]
    b1, b2 = metrics["baseline_config1"], metrics["baseline_config2"]
    ds = metrics["dataset"]
    lines = [
        "# Training report: Bag-of-Words + SVM (tactile handover events)",
        "",
        "Made by:",
        "",
        "```",
        command,
        "```",
        "",
    ]
    if syn:
        lines += [
            "> **All numbers on this page are synthetic**: the data come from the simulated hand "
            f"({metrics['data']}), not from people and a robot. They show that the pipeline works "
            "end to end; they say nothing about accuracy on a real SDH-2.",
            "",
        ]
    lines += [
        "## Data",
        "",
        f"- source: {metrics['data']}",
        f"- fingerprint (sha256 of frames, time stamps, labels): `{metrics['fingerprint'][:16]}...`",
        f"- pads {ds['pads']} ({metrics['pads']}), {sum(ds['pad_sizes'])} taxel series per case, "
        f"T = {metrics['T']} frames at {ds['sample_rate_hz']:.1f} Hz",
        f"- trigger: any taxel of these pads >= {ds['trigger_fraction']:.2f} x full scale ({ds['fullscale']:.0f}), "
        "the runtime's rule (rising edge; a trial already above the level at its first frame triggers only after "
        f"dropping below {ds['trigger_fraction'] - ds.get('trigger_hysteresis', 0.0):.2f} x full scale)",
        f"- labelled trials: {metrics['n_trials']}; cases: {ds['n_cases']}; "
        f"**untriggered: {metrics['n_untriggered']}** {ds['untriggered_reasons'] or ''} (listed in metrics.json, "
        "not padded, not in any split)",
        f"- cases per class: {ds['per_class']}; per subject: {ds['per_subject']}",
    ]
    if ds.get("trigger_minus_onset_frames"):
        d = ds["trigger_minus_onset_frames"]
        lines.append(f"- trigger frame minus annotated action onset: median {d['median']:.0f}, "
                     f"range {d['min']}..{d['max']} frames")
    if "windows_before_onset" in ds:
        lines.append(f"- **windows that end before the annotated onset: {ds['windows_before_onset']}** of "
                     f"{ds['n_cases_with_onset']} cases with an onset (their T frames cannot see the action)")
    lines += [
        "",
        "## Model",
        "",
        f"Feature families: {', '.join(metrics.get('families', ['bow']))} (trainer/feature_svc.py). "
        f"BoW: K = {metrics['K']} words, "
        + (f"W = {metrics['W']}" if len(metrics.get("windows", [0])) < 2 else
           f"windows W = {', '.join(str(w) for w in metrics['windows'])} (one codebook each)")
        + f", T = {metrics['T']}, per-pad histograms: "
        f"{metrics['per_pad']}; SVM kernel {metrics['kernel']}, one-vs-one, "
        f"C/gamma of the final model {metrics['best_params']} (chosen by stratified 3-fold search on "
        "the training cases of each fit). The final model is trained on all cases.",
        *_margin_lines(metrics.get("svm_margin")),
        "",
        f"## Results ({label})",
        "",
        "| | BoW + SVM | hand features + SVM (baseline) |",
        "|---|---|---|",
        f"| configuration 1: pooled, stratified random 80/20, {len(c1['accuracies'])} seeds (mean +/- std) | "
        f"{_pct(c1['mean'])} +/- {_pct(c1['std'])} | {_pct(b1['mean'])} +/- {_pct(b1['std'])} |",
        f"| configuration 2: leave one subject out (all held-out predictions) | {_pct(c2['accuracy'])} | "
        f"{_pct(b2['accuracy'])} |",
        f"| configuration 2: mean +/- std over subjects | {_pct(c2['subject_mean'])} +/- {_pct(c2['subject_std'])} | "
        f"{_pct(b2['subject_mean'])} +/- {_pct(b2['subject_std'])} |",
        "",
        f"Splits: configuration 1 = {c1['split']}. Configuration 2 = {c2['split']}.",
        "",
        "Leave-one-subject-out, per held-out subject:",
        "",
        "| subject | BoW + SVM | baseline |",
        "|---|---|---|",
    ]
    for s, acc in c2["per_subject"].items():
        lines.append(f"| {s} | {_pct(acc)} | {_pct(b2['per_subject'][s])} |")
    lines += ["", "Per class, configuration 1 (summed over seeds):", "", *_class_table(c1["per_class"]),
              "", "Per class, configuration 2:", "", *_class_table(c2["per_class"]), ""]
    sw = metrics.get("sweep")
    if sw:
        lines += [
            f"## Sweeps ({label})",
            "",
            f"{sw['description']}",
            "",
            "| parameter | value | kernel | accuracy | std |",
            "|---|---|---|---|---|",
        ]
        for r in sw["rows"]:
            lines.append(f"| {r['param']} | {r[r['param']]} | {r.get('kernel', 'rbf')} | {_pct(r['accuracy'])} | "
                         f"{_pct(r.get('std', 0.0))} |")
        lines.append("")
    lines += ["## Figures", ""]
    for title, name in figures.items():
        lines += [f"### {title}", "", f"![{title}]({name})", ""]
    lines += [
        "## Files",
        "",
        "- `metrics.json`: every number above, the untriggered trials, the confusion matrices",
        "- `model.joblib`: the fitted estimator (scikit-learn) and the model file's metadata "
        "(`{\"model\": ..., \"metadata\": ...}`; `handover export model.joblib` rebuilds the same model.onnx)",
        f"- `model.onnx`: {metrics.get('onnx') or 'not written'}",
        "",
        f"Took {metrics['seconds']:.0f} s.",
        "",
    ]
    path = out / "report.md"
    path.write_text("\n".join(lines))
    return path


def write_metrics(out: Path, metrics: dict) -> Path:
    path = out / "metrics.json"
    path.write_text(json.dumps(metrics, indent=1, sort_keys=False, default=_json_default))
    return path


def _json_default(obj):
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        return float(obj)
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")
