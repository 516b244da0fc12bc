"""What a training run leaves behind: the metrics, the model files with their card, the figures
and the headline for the terminal (``trainer.pipeline.train`` calls these in that order)."""

from __future__ import annotations

import sys
from pathlib import Path

from trainer.train_options import TrainOptions

__all__ = ["figures", "headline", "metrics_of", "write_model"]


def metrics_of(options: TrainOptions, ds, model, evaluation: dict, sweep: dict | None, selection, *, source: str,
               synthetic: bool) -> dict:
    """metrics.json: where the data came from, both configurations against the baseline, the settings.
    With one subject the configuration-2 fields are None and ``loso_unavailable`` says why."""
    from trainer.classifier import margin_report

    c1, c2 = evaluation["config1"], evaluation["config2"] or {}
    b1, b2 = evaluation["baseline_config1"], evaluation["baseline_config2"] or {}
    missing = {"loso_unavailable": evaluation["loso_unavailable"]} if "loso_unavailable" in evaluation else {}
    window = options.window
    windows = [int(w) for w in window] if isinstance(window, tuple) else [int(window)]
    return {
        "synthetic": synthetic,
        "data": source,
        "fingerprint": ds.fingerprint,
        "config1_accuracy_mean": c1["mean"],
        "config1_accuracy_std": c1["std"],
        "loso_accuracy": c2.get("accuracy"),
        "loso_per_subject": c2.get("per_subject"),
        "loso_subject_std": c2.get("subject_std"),
        "loso_skipped": c2.get("skipped") or {},
        **missing,
        "baseline_config1_accuracy_mean": b1["mean"],
        "baseline_config1_accuracy_std": b1["std"],
        "baseline_loso_accuracy": b2.get("accuracy"),
        "baseline_loso_subject_std": b2.get("subject_std"),
        "K": options.K, "W": max(windows), "windows": windows, "T": options.T, "kernel": model.kernel,
        "families": list(getattr(model, "families", ("bow",))),
        "feature_weighting": getattr(model, "feature_weighting", None), "selection": selection and selection.to_dict(),
        "per_pad": options.per_pad, "pads": options.pads, "trigger_fraction": ds.fraction,
        "trigger": ds.trigger.to_meta(), "trigger_hysteresis": ds.hysteresis, "seed": options.seed,
        "best_params": model.best_params_,
        "svm_margin": margin_report(model.svm_),
        "svm_notes": list(getattr(model, "svm_notes_", [])),
        **ds.counts().to_meta(),
        "n_windows_before_onset": ds.windows_before_onset,
        "untriggered": [s.to_dict() for s in ds.untriggered],
        "dataset": ds.summary(),
        "config1": c1, "config2": evaluation["config2"], "baseline_config1": b1,
        "baseline_config2": evaluation["baseline_config2"],
        "sweep": sweep,
    }


def write_model(options: TrainOptions, ds, model, metrics: dict, out: Path, early=None) -> bool:
    """model.joblib and (unless ``no_onnx``) model.onnx, with ``early`` heads (trainer.early) when given;
    sets ``metrics["onnx"]``. False: the export failed."""
    import joblib

    model_meta = model_metadata(options, ds, metrics)
    joblib_path = out / "model.joblib"
    joblib.dump({"model": model, "metadata": model_meta, "early": early}, joblib_path)
    if options.no_onnx:
        metrics["onnx"] = None
        return True
    onnx_ok, metrics["onnx"] = _export_onnx(model, model_meta, joblib_path, out, early)
    return onnx_ok


def model_metadata(options: TrainOptions, ds, metrics: dict) -> dict:
    """What the model file must carry besides the estimator: pads, trigger, provenance, evaluation.

    Kept in model.joblib (``{"model": ..., "metadata": ...}``) so ``handover export`` of that
    file writes the same model card as ``train``.
    """
    from trainer.model_meta import dataset_metadata
    from trainer.own_replay import real_false_meta

    # where the recordings are, so `handover verify MODEL` checks against the user's own data by default
    folder = {"data_folder": str(Path(options.data[0]).resolve())} if options.data else {}
    from runtime.training_counts import TrainingCounts
    from trainer.dormant import DORMANT

    return real_false_meta(metrics.get("own_replay")) | dataset_metadata(
        ds,
        dormant_class=DORMANT if DORMANT in ds.classes else None,
        training={
            "data": metrics["data"],
            **folder,
            "synthetic": metrics["synthetic"],
            "seed": options.seed,
            "C": metrics["best_params"].get("C"),
            "gamma": metrics["best_params"].get("gamma"),
            "hard_margin": metrics["svm_margin"]["hard_margin"],
            "support_vectors_at_bound": metrics["svm_margin"]["share_at_bound"],
            **({"idle_seconds": metrics["idle"]["seconds"]} if metrics.get("idle") else {}),
            **({"dormant_cut": metrics["idle"]["cut"]} if (metrics.get("idle") or {}).get("dormant_class") else {}),
            **({"prior": {k: metrics["prior"][k] for k in ("weight", "recipe")}}
               if (metrics.get("prior") or {}).get("recipe") else {}),
            **TrainingCounts.from_meta(metrics).to_meta(),  # the lab's windows and the prior's (simulated) beside them
        },
        evaluation={
            "synthetic": metrics["synthetic"],
            "config1_accuracy_mean": metrics["config1_accuracy_mean"],
            "config1_accuracy_std": metrics["config1_accuracy_std"],
            "config1_split": metrics["config1"]["split"],
            "loso_accuracy": metrics["loso_accuracy"],
            "loso_per_subject": metrics["loso_per_subject"],
            **({"loso_skipped": metrics["loso_skipped"]} if metrics.get("loso_skipped") else {}),
            "baseline_loso_accuracy": metrics["baseline_loso_accuracy"],
            **({"loso_unavailable": metrics["loso_unavailable"]} if "loso_unavailable" in metrics else {}),
        },
    )


def _export_onnx(model, meta: dict, joblib_path: Path, out: Path, early=None) -> tuple[bool, str]:
    """model.onnx beside model.joblib, whose sha256 it records as ``reference`` (so ``handover verify``
    refuses a mismatching pair). A failure is reported on stderr and makes ``train`` exit 1."""
    import hashlib

    from trainer.onnx_export import export_onnx

    digest = hashlib.sha256(joblib_path.read_bytes()).hexdigest()
    meta = {**meta, "reference": {"file": joblib_path.name, "sha256": digest}}
    try:
        path = export_onnx(model, out / "model.onnx", meta, early=early)
    except Exception as exc:  # the report is still worth having; say what failed, exit non-zero
        print(f"handover train: model.onnx not written: {type(exc).__name__}: {exc}", file=sys.stderr)
        return False, f"export failed: {type(exc).__name__}: {exc}"
    return True, f"written ({path.name}, {path.stat().st_size} bytes)"


def figures(options: TrainOptions, ds, embedding, metrics: dict, out: Path) -> dict[str, str]:
    """The report's PNGs, by caption -> file name."""
    from trainer import report

    synthetic = metrics["synthetic"]
    c1, c2 = metrics["config1"], metrics["config2"]
    tag = " (synthetic)" if synthetic else ""
    shown = {
        "Confusion matrix, configuration 1": report.plot_confusion(
            c1["confusion"], c1["labels"], f"config 1: pooled 80/20, {options.repeats} seeds{tag}",
            out / "confusion_config1.png").name,
    }
    if c2 is not None:
        shown["Confusion matrix, configuration 2"] = report.plot_confusion(
            c2["confusion"], c2["labels"], f"config 2: leave one subject out{tag}", out / "confusion_loso.png").name
    shown |= {
        f"{report.model_label(metrics['families'])} vs the hand-designed baseline": report.plot_model_vs_baseline(
            metrics, out / "model_vs_baseline.png", synthetic).name,
        f"t-SNE of the {report.features_label(metrics['families'])}": report.plot_tsne(
            embedding, ds.y, out / "tsne.png", synthetic, metrics["families"]).name,
    }
    sweep = metrics["sweep"]
    if sweep:
        values = {"K": options.K, "W": options.W, "T": options.T}
        for param in ("K", "W", "T"):
            rows = [r for r in sweep["rows"] if r["param"] == param]
            if rows:
                fixed = ", ".join(f"{p}={values[p]}" for p in ("K", "W", "T") if p != param)
                shown[f"Accuracy vs {param}"] = report.plot_sweep(
                    rows, param, fixed, out / f"sweep_{param}.png", synthetic).name
    return shown


def headline(metrics: dict, out: Path, onnx_written: bool) -> str:
    """The result on the terminal: data, the two accuracies against the baseline, where the files went."""
    from runtime.training_counts import TrainingCounts
    from trainer.early_report import console_line
    from trainer.own_replay import real_idle_line, replay_lines
    from trainer.prior import choice_lines
    from trainer.report import pct, pooled_text

    tag = "synthetic data" if metrics["synthetic"] else ""
    model = out / "model.onnx"
    # K (words) and W (derivative window) mean something only to the BoW family
    bow = f"K={metrics['K']} W={metrics['W']} " if "bow" in metrics["families"] else ""
    weighting = f" ({metrics['feature_weighting']})" if metrics.get("feature_weighting") else ""
    idle = metrics.get("idle")
    note = "; ".join(([f"{idle['seconds'] / 60:.1f} min recorded"] if idle else []) + ([tag] if tag else []))
    lines = [
        f"trained on {TrainingCounts.from_meta(metrics).text()}" + (f" ({note})" if note else "")
        + f", pads {metrics['pads']}, features {'+'.join(metrics['families'])}{weighting}, {bow}"
        f"T={metrics['T']} {metrics['kernel']} SVM"
        + (f" (--select: {metrics['selection']['winner']})" if metrics.get("selection") else ""),
        f"  leave one subject out: {pct(metrics['loso_accuracy'])} (hand-designed baseline "
        f"{pct(metrics['baseline_loso_accuracy'])})"
        + (f"; skipped (no second class to train on): {', '.join(metrics['loso_skipped'])}"
           if metrics.get("loso_skipped") else "") if metrics["loso_accuracy"] is not None
        else f"  leave one subject out: not measured ({metrics['loso_unavailable']})",
        f"  pooled 80/20: {pooled_text(metrics['config1'])} (baseline "
        f"{pct(metrics['baseline_config1_accuracy_mean'])})",
        *(f"  {line}" for line in choice_lines(metrics.get("prior"))),
        *([f"  {early}"] if (early := console_line(metrics.get("early"))) else []),
        *(f"  held-out replay through the daemon: {line}" for line in replay_lines(metrics.get("own_replay"))),
        *([real_idle_line(metrics["real_idle"])] if metrics.get("real_idle") else []),
        f"  report: {out / 'report.md'} ({metrics['seconds']:.0f} s)",
        f"  model:  {model} (handover inspect {model}; drop it into the daemon's model folder, deploy/INSTALL.md)"
        if onnx_written else "  model:  no model.onnx written (model.joblib only)",
    ]
    return "\n".join(lines)
