"""``handover train``: train BoW + SVM on all data, evaluate as in the paper, write a report and the model.

Without ``--data`` the paper's protocol is simulated first (synthetic data, labelled so in
every number shown). Writes into ``--out``: report.md, metrics.json, PNG figures, model.joblib
and, when the ONNX exporter is present, model.onnx.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

COMMAND = "train"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", help="folder of .hrec recordings (default: simulate the paper's protocol)")
    parser.add_argument("--out", default="report", help="report folder (created; default ./report)")
    parser.add_argument("--pads", default="all", help="pad selection: all, distal, proximal, thumb, 1,3,5 ...")
    parser.add_argument("--K", type=int, default=10, help="number of words (k-means centres)")
    parser.add_argument("--W", type=int, default=7, help="sliding window length (frames)")
    parser.add_argument("--T", type=int, default=15, help="frames per case from the trigger")
    parser.add_argument("--features", help="feature families, comma-separated, from bow, stats, rocket, hand "
                        "(default: the product default of trainer/defaults.py, chosen in results/compare.md; "
                        "--no-per-pad and the BoW-only options below select bow alone, the paper's family)")
    parser.add_argument("--kernel", choices=("rbf", "linear"), default=None,
                        help="SVM kernel (default: the product default's; linear for bow alone, which matches "
                        "RBF's error on the simulated protocol with per-pad histograms and is faster)")
    parser.add_argument("--C", type=float, default=None, help="SVM C (default: cross-validated search)")
    parser.add_argument("--gamma", type=float, default=None, help="RBF gamma (default: cross-validated search)")
    parser.add_argument("--per-pad", action=argparse.BooleanOptionalAction, default=True,
                        help="one histogram per pad (default: on); --no-per-pad gives the paper's single histogram "
                        "per case (and bow alone: the paper's configuration)")
    parser.add_argument("--select", action="store_true",
                        help="choose family and settings by grouped cross-validation on the training data "
                        "(leave one subject out, else grouped by run) within --latency-budget-us, report the "
                        "runners-up, export the winner")
    parser.add_argument("--latency-budget-us", type=float, default=None,
                        help="--select: single-case p99 of the exported graph allowed (default 1000 us)")
    parser.add_argument("--windows", help="several window lengths at once, e.g. 5,7,9 (one codebook each; "
                        "replaces --W)")
    parser.add_argument("--assignment", choices=("hard", "soft"), default="hard",
                        help="codeword assignment (paper: hard nearest word)")
    parser.add_argument("--temperature", type=float, default=1.0,
                        help="soft assignment temperature, in units of the k-means spread")
    parser.add_argument("--level-features", action="store_true",
                        help="add per-pad mean level and slope (keeps static pressure)")
    parser.add_argument("--scale-features", action="store_true", help="standardise the features before the SVM")
    parser.add_argument("--trigger", choices=("onset", "threshold"), default=None,
                        help="what cuts the training windows (default: the daemon's default, the onset trigger; "
                        "threshold = the paper's fixed level, see --fraction); recorded in the model")
    parser.add_argument("--fraction", type=float, default=None,
                        help="threshold trigger level as a fraction of full scale (the paper: 0.15; implies "
                        "--trigger threshold)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulation, k-means and the splits")
    parser.add_argument("--repeats", type=int, default=5, help="seeds of configuration 1 (80/20 splits)")
    parser.add_argument("--sweep", dest="sweep_file", help="sweep.json from `handover sweep` (default: OUT/sweep.json "
                        "if present, else a small built-in sweep)")
    parser.add_argument("--no-sweep", action="store_true", help="skip the accuracy-vs-K/W/T figures")
    parser.add_argument("--no-onnx", action="store_true", help="do not export model.onnx")
    parser.add_argument("--json", action="store_true", help="print the metrics as JSON on stdout")
    parser.add_argument("--quiet", action="store_true", help="no progress bars or messages on stderr")


def command_line(args: argparse.Namespace) -> str:
    """The exact command that reproduces this run (written at the top of the report)."""
    parts = ["handover", "train"]
    if args.data:
        parts += ["--data", str(args.data)]
    parts += ["--out", str(args.out), "--pads", args.pads, "--K", str(args.K), "--W", str(args.W),
              "--T", str(args.T), "--features", ",".join(families_of(args)), "--kernel", kernel_of(args),
              "--seed", str(args.seed), "--repeats", str(args.repeats)]
    if args.trigger:
        parts += ["--trigger", args.trigger]
    if args.fraction is not None:
        parts += ["--fraction", str(args.fraction)]
    for flag, value in (("--C", args.C), ("--gamma", args.gamma), ("--sweep", args.sweep_file)):
        if value is not None:
            parts += [flag, str(value)]
    if args.windows:
        parts += ["--windows", args.windows]
    if args.assignment != "hard":
        parts += ["--assignment", args.assignment, "--temperature", str(args.temperature)]
    parts.append("--per-pad" if args.per_pad else "--no-per-pad")
    if getattr(args, "select", False):
        parts.append("--select")
        if args.latency_budget_us is not None:
            parts += ["--latency-budget-us", str(args.latency_budget_us)]
    for flag, on in (("--level-features", args.level_features),
                     ("--scale-features", args.scale_features), ("--no-sweep", args.no_sweep),
                     ("--no-onnx", args.no_onnx)):
        if on:
            parts.append(flag)
    return " ".join(parts)


def parse_windows(text: str) -> int | tuple[int, ...]:
    """``"5,7,9"`` -> (5, 7, 9); one length -> int (the paper's single codebook)."""
    try:
        lengths = tuple(int(p) for p in text.split(",") if p.strip())
    except ValueError:
        raise ValueError(f"--windows {text!r}: give window lengths separated by commas, e.g. 5,7,9") from None
    if not lengths or min(lengths) < 1 or len(set(lengths)) != len(lengths):
        raise ValueError(f"--windows {text!r}: lengths must be distinct integers >= 1")
    return lengths[0] if len(lengths) == 1 else lengths


def estimator_options(args) -> dict:
    """The BowSVC keyword arguments of the options beyond the paper (paper's values by default)."""
    return {"window": parse_windows(args.windows) if getattr(args, "windows", None) else args.W,
            "assignment": getattr(args, "assignment", "hard"), "temperature": getattr(args, "temperature", 1.0),
            "level_features": getattr(args, "level_features", False),
            "scale_features": getattr(args, "scale_features", False)}


def families_of(args) -> tuple[str, ...]:
    """The feature families asked for: ``--features``, else bow alone when a BoW-only option (or
    ``--no-per-pad``, the paper's configuration) is given, else the product default."""
    from trainer.defaults import DEFAULT_MODEL
    from trainer.feature_svc import FAMILIES

    text = getattr(args, "features", None)
    if text:
        names = tuple(p.strip() for p in text.split(",") if p.strip())
        bad = [n for n in names if n not in FAMILIES]
        if not names or bad or len(set(names)) != len(names):
            raise ValueError(f"--features {text!r}: give distinct names from {', '.join(FAMILIES)}, e.g. stats,bow")
        return names
    bow_only = (not getattr(args, "per_pad", True) or getattr(args, "windows", None)
                or getattr(args, "assignment", "hard") != "hard" or getattr(args, "level_features", False)
                or getattr(args, "scale_features", False))
    return ("bow",) if bow_only else tuple(DEFAULT_MODEL["families"])


def kernel_of(args) -> str:
    """``--kernel``, else linear for bow alone (BowSVC's product setting), else the default's kernel."""
    from trainer.defaults import BOW_ALONE_KERNEL, DEFAULT_MODEL

    if getattr(args, "kernel", None):
        return args.kernel
    return BOW_ALONE_KERNEL if families_of(args) == ("bow",) else str(DEFAULT_MODEL["kernel"])


def build_estimator(args, ds):
    """BowSVC for bow alone (every paper option), else FeatureSVC over the chosen families."""
    from trainer.classifier import BowSVC
    from trainer.feature_svc import FeatureSVC

    families = families_of(args)
    if families == ("bow",):
        return BowSVC(n_words=args.K, kernel=kernel_of(args), C=args.C, gamma=args.gamma, per_pad=args.per_pad,
                      pad_sizes=ds.pad_sizes if (args.per_pad or args.level_features) else None,
                      random_state=args.seed, fullscale=ds.fullscale, **estimator_options(args))
    shapes = [(ds.layout.matrices[p].cells_y, ds.layout.matrices[p].cells_x) for p in ds.pads]
    return FeatureSVC(families=families, pad_sizes=tuple(ds.pad_sizes), pad_shapes=shapes, kernel=kernel_of(args),
                      C=args.C, gamma=args.gamma, n_words=args.K, window=args.W, random_state=args.seed,
                      fullscale=ds.fullscale)


def _fail(message: str) -> int:
    print(f"handover {COMMAND}: {message}", file=sys.stderr)
    return 2


def main(args: argparse.Namespace) -> int:
    from firmware_io.layout import LayoutError
    from firmware_io.recording import RecordingError
    from trainer.dataset import DatasetError

    if args.K < 1 or args.W < 1 or args.T < 2:
        return _fail(f"K, W must be >= 1 and T >= 2 (got K={args.K}, W={args.W}, T={args.T})")
    try:
        uses_bow = "bow" in families_of(args)
    except ValueError as exc:
        return _fail(str(exc))
    if uses_bow and args.T - 1 < args.W:  # W is the BoW window: other families do not read it
        return _fail(f"W={args.W} needs T >= {args.W + 1} (got T={args.T})")
    if args.repeats < 2:
        return _fail("--repeats must be at least 2 (mean +/- std)")
    try:
        window_arg = parse_windows(args.windows) if args.windows else args.W
    except ValueError as exc:
        return _fail(str(exc))
    longest = max(window_arg) if isinstance(window_arg, tuple) else window_arg
    if uses_bow and longest > args.T - 1:
        return _fail(f"--windows {args.windows} needs T >= {longest + 1} (got T={args.T})")
    if not args.temperature > 0:
        return _fail(f"--temperature must be positive (got {args.temperature})")
    if args.latency_budget_us is not None and not args.latency_budget_us > 0:
        return _fail(f"--latency-budget-us must be positive (got {args.latency_budget_us})")
    try:
        return run(args)
    except (RecordingError, DatasetError, LayoutError, OSError) as exc:
        return _fail(str(exc))
    except ValueError as exc:
        return _fail(f"cannot train: {exc}")


def _progress(args, desc: str, total: int):
    from tqdm import tqdm

    def wrap(iterable):  # bars only on a terminal: a redirected log gets no carriage-return clutter
        return tqdm(iterable, desc=desc, total=total, file=sys.stderr, disable=args.quiet or not sys.stderr.isatty(),
                    leave=False)

    return wrap


def _say(args, text: str) -> None:
    if not args.quiet:
        print(text, file=sys.stderr, flush=True)


def load_or_simulate(args) -> tuple[list, str, bool]:
    """Recordings, a description of where they came from, and whether they are synthetic."""
    from firmware_io.recording import find_recordings, load_all

    if args.data:
        paths = find_recordings(args.data)
        if not paths:
            raise FileNotFoundError(f"{args.data}: no .hrec recordings in this folder")
        recs = load_all(paths)
        synthetic = any(_looks_simulated(r.meta) for r in recs)
        return recs, f"{len(paths)} recordings in {args.data}", synthetic
    try:
        from firmware_io.simulate import simulate_protocol
    except ImportError as exc:
        raise FileNotFoundError(f"no --data given and the simulator is not available ({exc})") from None
    _say(args, f"simulating the paper's protocol (seed {args.seed}) ...")
    recs = simulate_protocol(seed=args.seed)
    return recs, f"simulated protocol, firmware_io.simulate.simulate_protocol(seed={args.seed})", True


def _looks_simulated(meta: dict) -> bool:
    text = json.dumps(meta, default=str).lower()
    return bool(meta.get("synthetic")) or "simulat" in text or "synthetic" in text


def run(args) -> int:
    import joblib

    from trainer import report
    from trainer.baseline import BaselineSVC
    from trainer.classifier import margin_report
    from trainer.dataset import build_dataset, dataset_trigger
    from trainer.evaluation import config1, config2, tsne_embedding

    t0 = time.perf_counter()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    recordings, source, synthetic = load_or_simulate(args)
    ds = build_dataset(recordings, T=args.T, pads=args.pads, trigger=dataset_trigger(args.trigger, args.fraction))
    summary = ds.summary()
    _say(args, f"{ds.n_trials} trials, {len(ds.y)} cases, {ds.n_untriggered} untriggered "
               f"{summary['untriggered_reasons'] or ''}")
    if len(set(ds.y.tolist())) < 2 or len(ds.y) < 10:
        raise ValueError(f"only {len(ds.y)} triggered cases of {len(set(ds.y.tolist()))} classes: too few to train")

    selection = None
    if args.select:
        from trainer.select import select_model

        selection = select_model(ds, args, say=lambda text: _say(args, text))
        bow = selection.estimator
    else:
        bow = build_estimator(args, ds)
    shapes = [(ds.layout.matrices[p].cells_y, ds.layout.matrices[p].cells_x) for p in ds.pads]
    base = BaselineSVC(pad_shapes=shapes, kernel="rbf")
    seeds = list(range(args.seed, args.seed + args.repeats))
    n_subjects = len(set(ds.groups.tolist()))

    _say(args, "training the final model on all cases ...")
    model = bow.fit(ds.X, ds.y)
    _say(args, "evaluating (configuration 1, leave one subject out, baseline) ...")
    c1 = config1(bow, ds.X, ds.y, seeds=seeds, progress=_progress(args, "config 1 (BoW)", len(seeds)))
    c2 = config2(bow, ds.X, ds.y, ds.groups, progress=_progress(args, "LOSO (BoW)", n_subjects))
    b1 = config1(base, ds.X, ds.y, seeds=seeds, progress=_progress(args, "config 1 (baseline)", len(seeds)))
    b2 = config2(base, ds.X, ds.y, ds.groups, progress=_progress(args, "LOSO (baseline)", n_subjects))

    sweep = None if args.no_sweep else _sweeps(args, recordings, out)

    _say(args, f"t-SNE of the {report.features_label(getattr(model, 'families', ('bow',)))} ...")
    hist = model.transform_histograms(ds.X)
    embedding = tsne_embedding(hist, seed=args.seed)

    window_opt = estimator_options(args)["window"]
    windows = [int(w) for w in window_opt] if isinstance(window_opt, tuple) else [int(window_opt)]
    metrics = {
        "synthetic": synthetic,
        "data": source,
        "fingerprint": ds.fingerprint,
        "config1_accuracy_mean": c1["mean"],
        "config1_accuracy_std": c1["std"],
        "loso_accuracy": c2["accuracy"],
        "loso_per_subject": c2["per_subject"],
        "loso_subject_std": c2["subject_std"],
        "baseline_config1_accuracy_mean": b1["mean"],
        "baseline_config1_accuracy_std": b1["std"],
        "baseline_loso_accuracy": b2["accuracy"],
        "baseline_loso_subject_std": b2["subject_std"],
        "K": args.K, "W": max(windows), "windows": windows, "T": args.T, "kernel": model.kernel,
        "families": list(getattr(model, "families", ("bow",))), "selection": selection and selection.to_dict(),
        "per_pad": args.per_pad, "pads": args.pads, "trigger_fraction": ds.fraction, "trigger": ds.trigger.to_meta(),
        "trigger_hysteresis": ds.hysteresis, "seed": args.seed,
        "best_params": model.best_params_,
        "svm_margin": margin_report(model.svm_),
        "n_trials": ds.n_trials, "n_cases": len(ds.y), "n_untriggered": ds.n_untriggered,
        "n_windows_before_onset": ds.windows_before_onset,
        "untriggered": [s.to_dict() for s in ds.untriggered],
        "dataset": summary,
        "config1": c1, "config2": c2, "baseline_config1": b1, "baseline_config2": b2,
        "sweep": sweep,
    }

    model_meta = model_metadata(args, ds, metrics)
    joblib_path = out / "model.joblib"
    joblib.dump({"model": model, "metadata": model_meta}, joblib_path)
    onnx_ok = True
    if args.no_onnx:
        metrics["onnx"] = None
    else:
        onnx_ok, metrics["onnx"] = _export_onnx(model, model_meta, joblib_path, out)

    _say(args, "writing figures and the report ...")
    tag = " (synthetic)" if synthetic else ""
    figures = {
        "Confusion matrix, configuration 1": report.plot_confusion(
            c1["confusion"], c1["labels"], f"config 1: pooled 80/20, {len(seeds)} seeds{tag}",
            out / "confusion_config1.png").name,
        "Confusion matrix, configuration 2": report.plot_confusion(
            c2["confusion"], c2["labels"], f"config 2: leave one subject out{tag}", out / "confusion_loso.png").name,
        f"{report.model_label(metrics['families'])} vs the hand-designed baseline": report.plot_model_vs_baseline(
            metrics, out / "model_vs_baseline.png", synthetic).name,
        f"t-SNE of the {report.features_label(metrics['families'])}": report.plot_tsne(
            embedding, ds.y, out / "tsne.png", synthetic, metrics["families"]).name,
    }
    if sweep:
        for param in ("K", "W", "T"):
            rows = [r for r in sweep["rows"] if r["param"] == param]
            if rows:
                fixed = ", ".join(f"{p}={args.__dict__[p]}" for p in ("K", "W", "T") if p != param)
                figures[f"Accuracy vs {param}"] = report.plot_sweep(
                    rows, param, fixed, out / f"sweep_{param}.png", synthetic).name
    metrics["seconds"] = round(time.perf_counter() - t0, 1)
    metrics["command"] = command_line(args)
    report.write_metrics(out, metrics)
    md_path = report.write_markdown(out, metrics, metrics["command"], figures)
    if selection is not None:
        from trainer.select import markdown_lines

        md_path.write_text(md_path.read_text() + "\n".join(markdown_lines(selection)) + "\n")
    if not args.quiet:
        print(headline(metrics, out, onnx_written=onnx_ok and not args.no_onnx), flush=True,
              file=sys.stderr if args.json else sys.stdout)
    if args.json:
        print(json.dumps({k: v for k, v in metrics.items() if not isinstance(v, dict) or k in (
            "loso_per_subject", "best_params", "svm_margin")}, default=report._json_default))
    return 0 if onnx_ok else 1


def headline(metrics: dict, out: Path, onnx_written: bool) -> str:
    """The result on the terminal: data, the two accuracies against the baseline, where the files went."""
    from trainer.report import pct, pooled_text

    tag = "synthetic data, " if metrics["synthetic"] else ""
    model = out / "model.onnx"
    # K (words) and W (derivative window) mean something only to the BoW family
    bow = f"K={metrics['K']} W={metrics['W']} " if "bow" in metrics["families"] else ""
    lines = [
        f"trained on {metrics['n_cases']} cases of {metrics['n_trials']} trials ({tag}{metrics['n_untriggered']} "
        f"never triggered), pads {metrics['pads']}, features {'+'.join(metrics['families'])}, {bow}"
        f"T={metrics['T']} {metrics['kernel']} SVM"
        + (f" (--select: {metrics['selection']['winner']})" if metrics.get("selection") else ""),
        f"  leave one subject out: {pct(metrics['loso_accuracy'])} (hand-designed baseline "
        f"{pct(metrics['baseline_loso_accuracy'])})",
        f"  pooled 80/20: {pooled_text(metrics['config1'])} (baseline "
        f"{pct(metrics['baseline_config1_accuracy_mean'])})",
        f"  report: {out / 'report.md'} ({metrics['seconds']:.0f} s)",
        f"  model:  {model} (handover inspect {model}; drop it into the daemon's model folder, deploy/INSTALL.md)"
        if onnx_written else "  model:  no model.onnx written (model.joblib only)",
    ]
    return "\n".join(lines)


def _sweeps(args, recordings, out: Path) -> dict | None:
    from trainer.sweeps import QUICK_K, QUICK_T, QUICK_W, run_sweeps

    path = Path(args.sweep_file) if args.sweep_file else out / "sweep.json"
    if path.is_file():
        _say(args, f"sweep results from {path}")
        try:
            return json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise FileNotFoundError(f"{path}: not a sweep result ({exc})") from None
    if args.sweep_file:
        raise FileNotFoundError(f"{path}: no such sweep result")
    base = {"K": args.K, "W": args.W, "T": args.T, "seed": args.seed, "per_pad": args.per_pad}
    seeds = (args.seed, args.seed + 1)
    n = len(QUICK_K) + len(QUICK_W) + len(QUICK_T)
    _say(args, "small built-in sweep of K, W, T (`handover sweep` runs the full one) ...")
    result = run_sweeps(recordings, base, QUICK_K, QUICK_W, QUICK_T, [kernel_of(args)], args.pads, args.fraction,
                        mode="config1", seeds=seeds, progress=_progress(args, "sweep", n))
    result["description"] = "Small built-in sweep. " + result["description"]
    return result


def model_metadata(args, ds, metrics: dict) -> dict:
    """What the model file must carry besides the estimator: pads, trigger, provenance, evaluation.

    Kept in model.joblib (``{"model": ..., "metadata": ...}``) so ``handover export`` of that
    file writes the same model card as ``train``.
    """
    from runtime import __version__

    rate = ds.sample_rate_hz if ds.sample_rate_hz == ds.sample_rate_hz else 32.0
    # where the recordings are, so `handover verify MODEL` checks against the user's own data by default
    folder = {"data_folder": str(Path(args.data).resolve())} if getattr(args, "data", None) else {}
    return {
        "pads": list(ds.pads),
        "pad_sizes": list(ds.pad_sizes),
        "fullscale": ds.fullscale,
        "trigger": ds.trigger.to_meta(),
        "sample_rate_hz": rate,
        "training": {
            "data_fingerprint": ds.fingerprint,
            "data": metrics["data"],
            **folder,
            "synthetic": metrics["synthetic"],
            "n_trials": ds.n_trials,
            "n_cases": len(ds.y),
            "n_untriggered": ds.n_untriggered,
            "project_version": __version__,
            "date": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "seed": args.seed,
            "C": metrics["best_params"].get("C"),
            "gamma": metrics["best_params"].get("gamma"),
            "hard_margin": metrics["svm_margin"]["hard_margin"],
            "support_vectors_at_bound": metrics["svm_margin"]["share_at_bound"],
        },
        "evaluation": {
            "synthetic": metrics["synthetic"],
            "config1_accuracy_mean": metrics["config1_accuracy_mean"],
            "config1_accuracy_std": metrics["config1_accuracy_std"],
            "config1_split": metrics["config1"]["split"],
            "loso_accuracy": metrics["loso_accuracy"],
            "loso_per_subject": metrics["loso_per_subject"],
            "baseline_loso_accuracy": metrics["baseline_loso_accuracy"],
        },
    }


def _export_onnx(model, meta: dict, joblib_path: Path, out: Path) -> tuple[bool, str]:
    """model.onnx beside model.joblib, whose sha256 it records as ``reference`` (so ``handover verify``
    refuses a mismatching pair). A failure is reported on stderr and makes ``train`` exit 1."""
    import hashlib

    from trainer.onnx_export import export_onnx

    digest = hashlib.sha256(joblib_path.read_bytes()).hexdigest()
    meta = {**meta, "reference": {"file": joblib_path.name, "sha256": digest}}
    try:
        path = export_onnx(model, out / "model.onnx", meta)
    except Exception as exc:  # the report is still worth having; say what failed, exit non-zero
        print(f"handover {COMMAND}: model.onnx not written: {type(exc).__name__}: {exc}", file=sys.stderr)
        return False, f"export failed: {type(exc).__name__}: {exc}"
    return True, f"written ({path.name}, {path.stat().st_size} bytes)"
