"""The report folder: figures (readable PNGs, 1200 px wide), ``metrics.json`` and a Markdown page people read.

Every figure and table says whether its numbers come from synthetic (simulated) data and
which split produced them.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from runtime.training_counts import TrainingCounts
from runtime.trigger_settings import window_start_text

__all__ = [
    "features_label", "model_label", "pct", "plot_confusion", "plot_model_vs_baseline", "plot_sweep", "plot_tsne",
    "pooled_text", "write_markdown", "write_metrics"
]

DPI = 150
WIDE = (8.0, 5.0)
"""Figure size in inches: at DPI 150, 1200 x 750 px, text at 11 pt readable on a screen."""
SQUARE = (8.0, 7.0)


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"font.size": 11, "axes.titlesize": 12, "legend.fontsize": 10})
    return plt


def _tag(synthetic: bool) -> str:
    return " (synthetic data)" if synthetic else ""


def plot_confusion(cm: Sequence[Sequence[int]], labels: Sequence[str], title: str, path: Path) -> Path:
    plt = _plt()
    cm = np.asarray(cm, dtype=float)
    rows = cm / np.maximum(cm.sum(axis=1, keepdims=True), 1)
    fig, ax = plt.subplots(figsize=SQUARE, dpi=DPI)
    ax.imshow(rows, cmap="Blues", vmin=0, vmax=1)
    for i in range(len(labels)):
        for j in range(len(labels)):
            ax.text(j, i, f"{int(cm[i, j])}\n{100 * rows[i, j]:.0f} %", ha="center", va="center",
                    color="white" if rows[i, j] > 0.6 else "black", fontsize=13)
    ax.set_xticks(range(len(labels)), labels)
    ax.set_yticks(range(len(labels)), labels)
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_sweep(rows: list[dict], param: str, fixed: str, path: Path, synthetic: bool) -> Path:
    """Accuracy against one parameter (one line per kernel)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=WIDE, dpi=DPI)
    for kernel in sorted({r.get("kernel", "rbf") for r in rows}):
        pts = sorted((r[param], r["accuracy"], r.get("std", 0.0)) for r in rows if r.get("kernel", "rbf") == kernel)
        x, acc, std = (np.array(v) for v in zip(*pts, strict=True))
        ax.errorbar(x, acc * 100, yerr=std * 100, marker="o", ms=5, capsize=3, label=kernel)
    ax.set_xlabel(param)
    ax.set_ylabel("accuracy %")
    ax.set_title(f"accuracy vs {param} ({fixed}){_tag(synthetic)}")
    ax.grid(alpha=0.3)
    ax.legend(title="kernel")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def model_label(families) -> str:
    """What the trained model is, for tables and figures: ``BoW + SVM`` or e.g. ``hand + stats features + SVM``."""
    families = list(families or ["bow"])
    return "BoW + SVM" if families == ["bow"] else f"{' + '.join(families)} features + SVM"


def features_label(families) -> str:
    """What the model's feature vector is: ``BoW histograms`` or e.g. ``hand + stats features``."""
    families = list(families or ["bow"])
    return "BoW histograms" if families == ["bow"] else f"{' + '.join(families)} features"


def plot_tsne(embedding: np.ndarray, y: np.ndarray, path: Path, synthetic: bool, families=("bow",)) -> Path:
    """t-SNE of the feature vectors the SVM sees (before scaling), one colour per class."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=SQUARE, dpi=DPI)
    for label in sorted(set(y.tolist())):
        pick = y == label
        ax.scatter(embedding[pick, 0], embedding[pick, 1], s=12, label=label, alpha=0.7)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(f"t-SNE of the {features_label(families)}{_tag(synthetic)}")
    ax.legend(markerscale=2)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_model_vs_baseline(metrics: dict, path: Path, synthetic: bool) -> Path:
    """Grouped bars on an axis zoomed to the values (differences of 1 % must show), each bar labelled,
    the legend below the axes where it covers nothing."""
    plt = _plt()
    names = ["config 1 (pooled 80/20)", "config 2 (leave one subject out)"]
    series = [
        (model_label(metrics.get("families")), [metrics["config1_accuracy_mean"], metrics["loso_accuracy"]],
         [metrics["config1_accuracy_std"], metrics["loso_subject_std"]]),
        ("hand-designed features + SVM", [metrics["baseline_config1_accuracy_mean"], metrics["baseline_loso_accuracy"]],
         [metrics["baseline_config1_accuracy_std"], metrics["baseline_loso_subject_std"]]),
    ]
    if metrics["loso_accuracy"] is None:  # one subject: configuration 2 was not measured, show configuration 1
        names = names[:1]
        series = [(label, values[:1], errors[:1]) for label, values, errors in series]
    x = np.arange(len(names))
    low, high = _zoomed_limits(series)
    fig, ax = plt.subplots(figsize=WIDE, dpi=DPI)
    for k, (label, values, errors) in enumerate(series):
        vals, errs = np.array(values) * 100, np.array(errors) * 100
        xs = x + (k - 0.5) * 0.38
        ax.bar(xs, vals, 0.36, yerr=errs, capsize=4, label=label)
        for xi, v in zip(xs, vals, strict=True):  # inside the bar, clear of the error bar
            ax.text(xi, low + 0.04 * (high - low), f"{v:.1f} %", ha="center", va="bottom", color="white",
                    fontweight="bold")
    ax.set_ylim(low, high)
    ax.set_xticks(x, names)
    ax.set_ylabel("accuracy % (axis does not start at 0)")
    ax.grid(axis="y", alpha=0.3)
    ax.set_title(f"{model_label(metrics.get('families'))} vs hand-designed features{_tag(synthetic)}")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=2, frameon=False)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def _zoomed_limits(series: list) -> tuple[float, float]:
    """A y range (in %) around the bars and their error bars (not from 0: differences of 1 % must show)."""
    lo = min(100 * (v - e) for _, values, errors in series for v, e in zip(values, errors, strict=True))
    hi = max(100 * (v + e) for _, values, errors in series for v, e in zip(values, errors, strict=True))
    span = max(hi - lo, 2.0)
    return max(0.0, lo - 0.3 * span), min(100.0 + 0.02 * span, hi + 0.1 * span)


def pct(v: float) -> str:
    """A fraction as people read it: 0.9663 -> 96.6 %."""
    return f"{100 * v:.1f} %"


def pooled_text(c1: dict) -> str:
    """Configuration 1 for people: mean +/- std and the range, or, when every split scored the same,
    that plain fact (a "+/- 0.0 %" reads like one split repeated; the splits do differ)."""
    accs = list(c1["accuracies"].values())
    n = len(accs)
    n_test = round(sum(map(sum, c1["confusion"])) / max(n, 1))
    if max(accs) - min(accs) < 1e-12:
        return f"{pct(accs[0])} on each of {n} different splits ({n_test} test cases each)"
    return f"{pct(c1['mean'])} +/- {pct(c1['std'])} over {n} splits (range {pct(min(accs))} .. {pct(max(accs))})"


def _class_table(per_class: dict) -> list[str]:
    lines = ["| class | precision | recall | support |", "|---|---|---|---|"]
    for c, v in per_class.items():
        lines.append(f"| {c} | {pct(v['precision'])} | {pct(v['recall'])} | {v['support']} |")
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
    label = "**synthetic**" if metrics["synthetic"] else "measured"
    lines = [*_header_lines(metrics, command), *_data_lines(metrics), *_model_lines(metrics),
             *_results_lines(metrics, label), *_replay_lines(metrics, label), *_sweep_lines(metrics.get("sweep"), label),
             *_closing_lines(metrics, figures)]
    path = out / "report.md"
    path.write_text("\n".join(lines))
    return path


def _header_lines(metrics: dict, command: str) -> list[str]:
    syn = metrics["synthetic"]
    lines = [
        f"# Training report: {model_label(metrics.get('families'))} (tactile handover events)",
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
    return lines


def _data_lines(metrics: dict) -> list[str]:
    ds = metrics["dataset"]
    lines = [
        "## Data",
        "",
        f"- source: {metrics['data']}",
        f"- fingerprint (sha256 of frames, time stamps, labels): `{metrics['fingerprint'][:16]}...`",
        f"- pads {ds['pads']} ({metrics['pads']}), {sum(ds['pad_sizes'])} taxel series per case, "
        f"T = {metrics['T']} frames at {ds['sample_rate_hz']:.1f} Hz",
        trigger_line(ds),
        f"- trained on {TrainingCounts.from_meta(metrics).text()}",
        f"- **labelled trials that gave no window: {ds['n_untriggered']}** "
        f"{''.join(f'({k}: {v}) ' for k, v in (ds['untriggered_reasons'] or {}).items())}"
        "(listed in metrics.json, not padded, not in any split)",
        f"- cases per class: {ds['per_class']}; per subject: {ds['per_subject']}",
        *_idle_lines(metrics.get("idle")),
        *(f"- **{line}** (trainer/data_warnings.py)" for line in metrics.get("data_notes", [])),
    ]
    if ds.get("trigger_minus_onset_frames"):
        d = ds["trigger_minus_onset_frames"]
        lines.append("- window start (where the trigger dates the departure) minus annotated action onset: "
                     f"median {d['median']:.0f}, "
                     f"range {d['min']}..{d['max']} frames")
    if "windows_before_onset" in ds:
        lines.append(f"- **windows that end before the annotated onset: {ds['windows_before_onset']}** of "
                     f"{ds['n_cases_with_onset']} cases with an onset (their T frames cannot see the action)")
    return lines


def _model_lines(metrics: dict) -> list[str]:
    return [
        "",
        "## Model",
        "",
        f"Feature families: {', '.join(metrics.get('families', ['bow']))} (trainer/feature_svc.py). "
        + _bow_settings(metrics)
        + f"T = {metrics['T']}; SVM kernel {metrics['kernel']}, one-vs-one, "
        f"C/gamma of the final model {metrics['best_params']} (chosen by stratified 3-fold search on "
        "the training cases of each fit). The final model is trained on all cases.",
        *_margin_lines(metrics.get("svm_margin")),
        *(f"- **{line}** (trainer/classifier.py, MAX_ITER)" for line in metrics.get("svm_notes", [])),
    ]


def _results_lines(metrics: dict, label: str) -> list[str]:
    c1, b1 = metrics["config1"], metrics["baseline_config1"]
    lines = [
        "",
        f"## Results ({label})",
        "",
        f"| | {model_label(metrics.get('families'))} | hand features + SVM (baseline) |",
        "|---|---|---|",
        f"| configuration 1: pooled, stratified random 80/20, {len(c1['accuracies'])} seeds (mean +/- std) | "
        f"{pct(c1['mean'])} +/- {pct(c1['std'])} | {pct(b1['mean'])} +/- {pct(b1['std'])} |",
        *_loso_rows(metrics),
        "",
    ]
    lines += _loso_lines(metrics, c1["split"])
    lines += ["", "Per class, configuration 1 (summed over seeds):", "", *_class_table(c1["per_class"]), ""]
    if metrics["config2"] is not None:
        lines += ["Per class, configuration 2:", "", *_class_table(metrics["config2"]["per_class"]), ""]
    return lines


def _loso_rows(metrics: dict) -> list[str]:
    """Configuration 2's rows of the results table, or one row saying why it was not measured."""
    c2, b2 = metrics["config2"], metrics["baseline_config2"]
    if c2 is None:
        return [f"| configuration 2: leave one subject out | not measured: {metrics['loso_unavailable']} | "
                "not measured |"]
    return [
        f"| configuration 2: leave one subject out (all held-out predictions) | {pct(c2['accuracy'])} | "
        f"{pct(b2['accuracy'])} |",
        f"| configuration 2: mean +/- std over subjects | {pct(c2['subject_mean'])} +/- {pct(c2['subject_std'])} | "
        f"{pct(b2['subject_mean'])} +/- {pct(b2['subject_std'])} |",
    ]


def _loso_lines(metrics: dict, split1: str) -> list[str]:
    """The splits, and configuration 2 per held-out subject (or why there is none)."""
    c2, b2 = metrics["config2"], metrics["baseline_config2"]
    if c2 is None:
        return [f"Splits: configuration 1 = {split1}. Configuration 2 (leave one subject out) was not measured: "
                f"{metrics['loso_unavailable']}. The model was trained and exported as usual; the figure above "
                "is for the people it was trained on, not for new people."]
    lines = [
        f"Splits: configuration 1 = {split1}. Configuration 2 = {c2['split']}.",
        "",
        "Leave-one-subject-out, per held-out subject:",
        "",
        f"| subject | {model_label(metrics.get('families'))} | baseline |",
        "|---|---|---|",
    ]
    partial = metrics.get("partial_subjects") or {}
    cases = metrics["dataset"].get("per_subject", {})
    for s, acc in c2["per_subject"].items():
        if s in partial:  # a handful of trials scored 100 % says nothing: say what the row rests on
            n = cases.get(s, 0)
            lines.append(f"| {s} | partial recording ({partial[s]}): {round(acc * n)} of {n} cases right | "
                         f"{round(b2['per_subject'][s] * n)} of {n} |")
            continue
        lines.append(f"| {s} | {pct(acc)} | {pct(b2['per_subject'][s])} |")
    for s, why in (c2.get("skipped") or {}).items():
        lines.append(f"| {s} | not measured: {why} | not measured |")
    return lines


def _idle_lines(idle: dict | None) -> list[str]:
    """Where the dormant class came from, or that there is none."""
    if not idle:
        return ["- idle recorded: none, so the model has no dormant class (`handover record` records idle after "
                "the trials; `handover import --idle` marks a file as idle)"]
    if idle.get("dormant_class") is False:  # older metrics lack the key: they made the class
        from trainer.recorded_idle import too_few_line

        lines = [f"- idle recorded: {too_few_line(idle['seconds'], idle['dormant_windows'], idle['cut'])}"]
        return lines + [f"- {note}" for note in idle.get("notes", [])]
    lines = [f"- idle recorded: {idle['seconds'] / 60:.1f} min; {idle['dormant_windows']} dormant windows "
             f"({', '.join(f'{k} {v}' for k, v in idle['per_origin'].items())}): the class `dormant` "
             "(trainer/recorded_idle.py)"]
    lines += [f"- {note}" for note in idle.get("notes", [])]
    return lines


def _replay_lines(metrics: dict, label: str) -> list[str]:
    """Each held-out subject's recording replayed through the daemon (trainer/own_replay.py)."""
    from trainer.own_replay import replay_lines

    r = metrics.get("own_replay")
    if not r:
        return []
    lines = ["", f"## Stream replay of held-out subjects ({label})", "",
             f"Each subject's recording (trials and idle stretches) replayed frame by frame through the daemon "
             f"in the stream setting `{r['mode']}`, with a model trained without that subject (trainer/own_replay.py; "
             f"early heads and rule chosen without that subject: {r.get('early_heads', 'none')}).",
             ""]
    if not r.get("folds"):
        return [*lines, f"Not measured: {'; '.join(f'{k}: {v}' for k, v in r.get('skipped', {}).items()) or '-'}", ""]
    lines += [f"- {line}" for line in replay_lines(r)]
    if metrics.get("real_idle"):
        from trainer.own_replay import real_idle_line

        lines.append(f"- {real_idle_line(metrics['real_idle']).strip()} (the final model)")
    lines += ["", "| held out | trials | right | wrong | missed | idle (min) | false events | per hour |",
              "|---|---|---|---|---|---|---|---|"]
    partial = metrics.get("partial_subjects") or {}
    for f in r["folds"]:
        fph = "-" if f["false_per_hour"] is None else f"{f['false_per_hour']:.1f}"
        held = f["held_out"] + (f" (partial: {partial[f['held_out']]})" if f["held_out"] in partial else "")
        lines.append(f"| {held} | {f['events']} | {f['right']} | {f['wrong']} | {f['missed']} | "
                     f"{f['idle_hours'] * 60:.1f} | {f['false_events']} | {fph} |")
    if r.get("idle_by_source"):
        lines += ["", "| idle source | minutes | false events | per hour |", "|---|---|---|---|"]
        for k, v in r["idle_by_source"].items():
            fph = "-" if v["false_per_hour"] is None else f"{v['false_per_hour']:.1f}"
            lines.append(f"| {k} | {v['hours'] * 60:.1f} | {v['false_events']} | {fph} |")
    for k, v in (r.get("skipped") or {}).items():
        lines.append(f"- {k}: not replayed ({v})")
    return [*lines, ""]


def _sweep_lines(sw: dict | None, label: str) -> list[str]:
    lines: list[str] = []
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
            lines.append(f"| {r['param']} | {r[r['param']]} | {r.get('kernel', 'rbf')} | {pct(r['accuracy'])} | "
                         f"{pct(r.get('std', 0.0))} |")
        lines.append("")
    return lines


def _closing_lines(metrics: dict, figures: dict[str, str]) -> list[str]:
    lines = ["## Figures", ""]
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
    return lines


def _bow_settings(metrics: dict) -> str:
    """K, W and per-pad of the BoW family, only when the model has one (they mean nothing to the others)."""
    if "bow" not in metrics.get("families", ["bow"]):
        return ""
    windows = (f"W = {metrics['W']}" if len(metrics.get("windows", [0])) < 2 else
               f"windows W = {', '.join(str(w) for w in metrics['windows'])} (one codebook each)")
    return f"BoW: K = {metrics['K']} words, {windows}, per-pad histograms: {metrics['per_pad']}; "


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


def trigger_line(ds: dict) -> str:
    """How the windows were cut (the runtime's trigger, as the model records it)."""
    trig = ds.get("trigger") or {}
    if trig.get("kind") == "onset":
        return (f"- trigger: onset (runtime/onset.py): a pad's summed pressure departs by {trig['change']:.0%} from the "
                f"settled grasp (the trial's first frame), {window_start_text(trig)}")
    return (f"- trigger: any taxel of these pads >= {ds['trigger_fraction']:.2f} x full scale ({ds['fullscale']:.0f}), "
            "the runtime's rule (rising edge; a trial already above the level at its first frame triggers only after "
            f"dropping below {ds['trigger_fraction'] - ds.get('trigger_hysteresis', 0.0):.2f} x full scale)")
