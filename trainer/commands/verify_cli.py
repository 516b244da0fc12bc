"""``handover verify MODEL.onnx [--data DIR] [--stress] [--json]``: the graph against float64.

Runs the exported graph and its float64 reference (the ``.joblib`` next to it) on the same windows:
``--data``, else the folder the model was trained on, else held-out simulated trials; ``--stress`` adds
``trainer.stress``'s families. Exit 0 when every disagreement is a near tie and no output is NaN/inf,
1 otherwise, 2 when it cannot run.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from firmware_io.commands.options import add_json, add_quiet, add_seed, positive_int, progress_to
from firmware_io.errors import HandoverError

__all__ = ["add_arguments", "main"]

STRIDE = 8
SUBJECTS = 2
"""Defaults sized for a check after each training (a few thousand held-out windows, about a minute on
a 2-core machine); results/verify_simulated.md ran the thorough ``--subjects 5 --stride 4``."""
PROGRESS_STEPS = 10

def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", help="exported model (.onnx)")
    parser.add_argument("--reference", help="the trained .joblib (default: as named in the model's metadata)")
    parser.add_argument("--data", help="folder of .hrec recordings (default: the folder the model was trained on, "
                        "if recorded and present; else a held-out simulated protocol)")
    add_seed(parser, 1000, "simulator seed of the held-out trials")
    parser.add_argument("--subjects", type=positive_int, default=SUBJECTS, help="simulated held-out subjects")
    parser.add_argument("--stride", type=positive_int, default=STRIDE, help="frames between verified window starts")
    parser.add_argument("--stress", action="store_true", help="add the stress cases")
    parser.add_argument("--no-trials", action="store_true", help="stress cases only (implies --stress)")
    add_json(parser, "the report")
    add_quiet(parser)


def verdict(report) -> str:
    """The first line: passed or failed, and why, before any figure a newcomer could misread."""
    n = report.n_cases
    agree = n - len(report.disagreements)
    if report.ok and report.nonfinite_input_refused:
        ties = (f" ({len(report.disagreements)} differ at near ties, where float32 rounding may pick either "
                "label)" if report.disagreements else "")
        return (f"PASSED: the graph gives the float64 reference's label on {agree} of {n} cases "
                f"({100 * report.agreement:.3f} %){ties}; every difference is within float32 rounding; "
                "no NaN/inf; non-finite input refused")
    why = []
    if report.unexplained_disagreements:
        why.append(f"{report.unexplained_disagreements} cases get another label than the reference, not at a near tie")
    if report.hist_mismatch_unexplained:
        why.append(f"{report.hist_mismatch_unexplained} {report.features}s differ beyond float32 rounding")
    if report.window_word_mismatches_unexplained:
        why.append(f"{report.window_word_mismatches_unexplained} windows pick another codeword beyond float32 rounding")
    if report.nan_or_inf_outputs:
        why.append(f"{report.nan_or_inf_outputs} NaN/inf outputs")
    if not report.nonfinite_input_refused:
        why.append("non-finite input is not refused")
    return "FAILED: " + "; ".join(why) + " (the graph does not compute what the float64 model does)"


def _print_report(report, path: Path) -> None:
    print(f"verify {path}: {verdict(report)}")
    print(f"details ({report.n_cases} cases; the verdict above counts, the lines below explain it):")
    for source, entry in sorted(report.by_source.items()):
        print(f"  {source}: {entry['agree']}/{entry['n_cases']} agree")
    print(f"  disagreements: {len(report.disagreements)} ({report.near_tie_disagreements} at near ties, "
          f"{report.unexplained_disagreements} unexplained: only unexplained ones fail)")
    codebook = report.codebook  # codewords mean something only to a model with the BoW family
    for d in report.disagreements[:50]:
        words = f"codeword margin {d.codeword_margin:.3g} x bound (gap {d.codeword_gap:.3g}), " if codebook else ""
        print(f"    case {d.case} [{d.source}] graph={d.graph_label} reference={d.reference_label}: {d.reason}; "
              f"{words}SVM margin {d.svm_margin:.3g} x bound")
    print(f"  largest |score - reference| (float32 rounding of the SVM scores, in score units): "
          f"{report.max_score_abs_diff:.3g} ({report.max_score_abs_diff_same_votes:.3g} where {report.features} "
          "and votes agree)")
    what = report.features
    print(f"  largest |{what} - reference| (in the features' own units, e.g. pressure sums of thousands): "
          f"{report.max_hist_abs_diff:.3g}; beyond their float32 bound: {report.hist_mismatch_cases} "
          f"({report.hist_mismatch_unexplained} not at a near tie: only these fail)")
    if codebook:
        print(f"  windows whose codeword differs from float64: {report.window_word_mismatches} "
              f"({report.window_word_mismatches_near_tie} near ties, {report.window_word_mismatches_unexplained} "
              "beyond the bound: only these fail)")
    share = 100 * report.near_tie_cases / max(report.n_cases, 1)
    print(f"  near ties (not failures; the label above was still compared): {report.near_tie_cases} cases "
          f"({share:.1f} %) lie so close to a boundary that the worst-case float32 bound alone cannot guarantee "
          f"their vote (the SVM decision in {report.svm_near_tie_cases})")
    print(f"  NaN/inf outputs: {report.nan_or_inf_outputs}; "
          f"non-finite input refused: {report.nonfinite_input_refused}")
    print(f"  near tie: margin < {report.safety:g} x the float32 error bound (see trainer/numerics.py)")


def _trial_stream(args, meta):
    """The user's --data, else the training folder the model names, else held-out simulated trials."""
    from trainer.verify_windows import recording_stream, simulated_stream, trained_data_folder

    if args.data:
        return recording_stream(args.data, meta, args.stride)
    folder = trained_data_folder(meta)
    if folder is not None and folder.is_dir():
        _note(args, f"verifying on the recordings the model was trained on ({folder}; --data to choose others)")
        return recording_stream(folder, meta, args.stride)
    if folder is not None:
        _note(args, f"the model was trained on {folder}, which is not here: verifying on held-out simulated "
                    "trials instead (--data DIR for your recordings)")
    return simulated_stream(meta, args.seed, args.subjects, args.stride)


def _note(args, text: str) -> None:
    progress_to(args.quiet)(f"handover verify: {text}")


def _run_stream(args, stream, compare_batch) -> None:
    """Compare batch by batch; a progress line about every 10 % (plain lines: fine in a log)."""
    total, done, next_step, t0 = stream.total, 0, 1, time.monotonic()
    for frames, sources in stream.batches():
        compare_batch(frames, sources)
        done += len(frames)
        if done * PROGRESS_STEPS >= next_step * total:
            next_step = done * PROGRESS_STEPS // total + 1
            _note(args, f"{done}/{total} windows of the {stream.source} ({100 * done / total:.0f} %, "
                        f"{time.monotonic() - t0:.0f} s)")


def main(args: argparse.Namespace) -> int:
    from runtime.model import load_model
    from trainer.verify import GraphRunner, VerifyReport, check_nonfinite_refused, compare, load_reference
    from trainer.verify_windows import stress_windows

    path = Path(args.model)
    try:
        loaded = load_model(path)
        meta = loaded.meta
        model = load_reference(path, meta.extra, args.reference, (meta.T, meta.n_channels))
        fold = bool(meta.extra.get("graph", {}).get("fold_derivative", False))
        runner = GraphRunner(path)
        report = VerifyReport()

        def compare_batch(frames, sources) -> None:
            compare(model, runner, frames, sources, fold, report)

        if not args.no_trials:
            _run_stream(args, _trial_stream(args, meta), compare_batch)
        if args.stress or args.no_trials:
            compare_batch(*stress_windows(model, meta))
        report.nonfinite_input_refused = check_nonfinite_refused(path)
    except (OSError, ValueError) as exc:  # every error of the model, reference and data is one of these
        raise HandoverError(str(exc)) from exc
    if args.json:
        print(json.dumps(report.to_dict(), indent=2))
    else:
        _print_report(report, path)
    return 0 if report.ok and report.nonfinite_input_refused else 1
