"""``handover train``: train the default features (or BoW, the paper's) + SVM on all data, evaluate as in
the paper, write a report and the model.

Without ``--data`` the paper's protocol is simulated first (synthetic data, labelled so in
every number shown). Writes into ``--out``: report.md, metrics.json, PNG figures, model.joblib
and, when the ONNX exporter is present, model.onnx. The arguments become ``TrainOptions`` once;
the work is ``trainer.pipeline.train``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from firmware_io.commands.options import add_json, add_out, add_quiet, add_seed, trigger_level
from firmware_io.errors import HandoverError
from runtime.trigger_settings import PAPER_FRACTION
from trainer.recorded_idle import DORMANT_CUTS
from trainer.train_options import (
    ASSIGNMENTS,
    EARLY,
    FEATURE_WEIGHTING_CHOICES,
    KERNELS,
    TRIGGERS,
    TrainOptions,
    parse_features,
    parse_windows,
)

__all__ = ["add_arguments", "main"]



def add_arguments(parser: argparse.ArgumentParser) -> None:
    D = TrainOptions  # the defaults, from their one owner
    parser.add_argument("--data", action="append", help="folder of .hrec recordings, or a daemon's capture folder "
                        "(its events labelled by `handover review`); once per folder (default: simulate the paper's "
                        "protocol)")
    add_out(parser, "report folder (created; default ./report)", default=D.out)
    parser.add_argument("--pads", default=D.pads, help="pad selection: all, distal, proximal, thumb, 1,3,5 ...")
    parser.add_argument("--K", type=int, default=D.K, help="number of words (k-means centres)")
    parser.add_argument("--W", type=int, default=D.W, help="sliding window length (frames)")
    parser.add_argument("--T", type=int, default=D.T, help="frames per case from the trigger")
    parser.add_argument("--features", help="feature families, comma-separated, from bow, stats, rocket, hand, image "
                        "(default: the product default of trainer/defaults.py, chosen in results/compare.md; "
                        "--no-per-pad and the BoW-only options below select bow alone, the paper's family)")
    parser.add_argument("--kernel", choices=KERNELS, default=None,
                        help="SVM kernel (default: the product default's; linear for bow alone, which matches "
                        "RBF's error on the simulated protocol with per-pad histograms and is faster)")
    parser.add_argument("--C", type=float, default=None, help="SVM C (default: cross-validated search)")
    parser.add_argument("--gamma", type=float, default=None, help="RBF gamma (default: cross-validated search)")
    parser.add_argument("--feature-weighting", choices=FEATURE_WEIGHTING_CHOICES, default=None,
                        help="reweigh the standardised features in the SVM's distance (trainer/feature_weighting.py): "
                        "distinct (a quantity two families both compute counts once), block_count or block_mfa "
                        "(every family weighs the same), none (unweighted); default: the product default's (distinct) with the "
                        "default families, else none")
    parser.add_argument("--per-pad", action=argparse.BooleanOptionalAction, default=D.per_pad,
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
    parser.add_argument("--assignment", choices=ASSIGNMENTS, default=D.assignment,
                        help="codeword assignment (paper: hard nearest word)")
    parser.add_argument("--temperature", type=float, default=D.temperature,
                        help="soft assignment temperature, in units of the k-means spread")
    parser.add_argument("--level-features", action="store_true",
                        help="add per-pad mean level and slope (keeps static pressure)")
    parser.add_argument("--scale-features", action="store_true", help="standardise the features before the SVM")
    parser.add_argument("--trigger", choices=TRIGGERS, default=None,
                        help="what cuts the training windows (default: the daemon's default, the onset trigger; "
                        "threshold = the paper's fixed level, see --fraction); recorded in the model")
    parser.add_argument("--fraction", type=trigger_level, default=None,
                        help=f"threshold trigger level as a fraction of full scale (the paper: {PAPER_FRACTION}; implies "
                        "--trigger threshold)")
    add_seed(parser, D.seed, "seed of the simulation, k-means and the splits")
    parser.add_argument("--repeats", type=int, default=D.repeats, help="seeds of configuration 1 (80/20 splits)")
    parser.add_argument("--sweep", dest="sweep_file", help="sweep.json from `handover sweep` (default: OUT/sweep.json "
                        "if present, else a small built-in sweep)")
    parser.add_argument("--no-sweep", action="store_true", help="skip the accuracy-vs-K/W/T figures")
    parser.add_argument("--no-onnx", action="store_true", help="do not export model.onnx")
    parser.add_argument("--dormant", action=argparse.BooleanOptionalAction, default=D.dormant,
                        help="with idle stretches in the recordings (handover record, import --idle), add the fifth "
                        "class 'dormant' the default stream setting serves (default: on); --no-dormant: the four "
                        "actions only")
    parser.add_argument("--replay", action=argparse.BooleanOptionalAction, default=D.replay,
                        help="replay each held-out subject's recording (trials and idle) through the daemon with a "
                        "model trained without it: events right, wrong, missed, false events per hour of idle "
                        "(default: on)")
    parser.add_argument("--prior", action=argparse.BooleanOptionalAction, default=D.prior,
                        help="with --data: train on the recordings plus what the simulator teaches (the paper's "
                        "protocol and idle of the default simulator, fixed seed), its weight chosen by leave one "
                        "lab subject out (docs/OWN_MODEL.md); --no-prior: the recordings alone (default: on)")
    parser.add_argument("--early", choices=EARLY, default=D.early,
                        help="on: early heads decide 4 to 11 frames after the window's start when their calibrated "
                        "confidence allows, rule chosen by grouped cross-validation (docs/EARLY.md); off: the full "
                        "window only")
    parser.add_argument("--dormant-cut", choices=DORMANT_CUTS, default=D.dormant_cut,
                        help="which idle windows train the dormant class, yours and the prior's: trigger = where the "
                        "trigger fires on the idle (what a model serving with the trigger is asked); in_view = "
                        "windows of every idle kind in view (what continuous mode asks); both = the two together "
                        f"(default: {D.dormant_cut}, chosen by ./dev bench streams_own)")
    parser.add_argument("--real-idle", action=argparse.BooleanOptionalAction, default=None,
                        help="replay the real SDH-2 recordings without a handover (../shared/data, "
                        "HANDOVER_SHARED_DATA) through the model: false events per hour (default: for real "
                        "recordings, where the folder is present; about a minute)")
    add_json(parser, "the metrics")
    add_quiet(parser, "no progress bars or messages: the result only (the headline: accuracies, the prior's weight, "
              "the early rule, the replay; with --json the JSON) and what the data can carry")


def options_from_args(args: argparse.Namespace) -> TrainOptions:
    """The one place the command's arguments become TrainOptions (OptionsError for unreadable lists)."""
    given = {k: v for k, v in vars(args).items() if k in TrainOptions.names()}
    given["features"] = parse_features(args.features) if args.features is not None else None
    given["windows"] = parse_windows(args.windows) if args.windows else None
    return TrainOptions(**given)


def main(args: argparse.Namespace) -> int:
    options = options_from_args(args)
    options.check()
    from firmware_io.commands.options import PROGRESS, out_folder
    from firmware_io.recordings.record_session import RECORD_OUT

    out_folder(options.out)  # before minutes of training, not after
    if options.data is None and any(Path(RECORD_OUT).glob("*.hrec")):  # record's default folder, not read unasked
        PROGRESS.warning(f"handover train: no --data, so the simulated protocol (synthetic) trains; the recordings "
                         f"in ./{RECORD_OUT} are read with --data {RECORD_OUT}")
    return run(options)


def run(options: TrainOptions) -> int:
    """Train; one line and exit 2 for data that cannot train, exit 1 when model.onnx was not written."""
    from trainer import report
    from trainer.pipeline import train

    try:
        result = train(options)
    except HandoverError:
        raise  # options, recordings, layout, data set: each says what is wrong itself
    except OSError as exc:
        raise HandoverError(str(exc)) from exc
    except ValueError as exc:  # from the estimators: data they cannot fit
        raise HandoverError(f"cannot train: {exc}") from exc
    if not (options.quiet and options.json):  # --quiet drops progress, not the result (with --json: the JSON)
        print(result.headline, flush=True, file=sys.stderr if options.json else sys.stdout)
    if options.json:
        metrics = result.metrics
        print(json.dumps({k: v for k, v in metrics.items() if not isinstance(v, dict) or k in (
            "loso_per_subject", "best_params", "svm_margin")}, default=report._json_default))
    return result.exit_code
