"""``handover sweep``: the paper's accuracy-vs-K, W, T curves (and kernel), longer than ``train``'s quick one.

Writes ``OUT/sweep.json`` (which ``handover train --out OUT`` then uses for its figures) and
``OUT/sweep_K.png``, ``sweep_W.png``, ``sweep_T.png``.
"""

from __future__ import annotations

import argparse
import json
import time

from firmware_io.commands.options import add_json, add_out, add_quiet, add_seed, out_folder, positive_int, trigger_level
from firmware_io.errors import HandoverError

__all__ = ["add_arguments", "main"]


def _ints(text: str) -> tuple[int, ...]:
    try:
        values = tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"expected positive integers, got {text!r}")
    return values


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from runtime.trigger_settings import PAPER_FRACTION
    from trainer.defaults import PAPER_MODEL
    from trainer.sweeps import FULL_K, FULL_T, FULL_W

    parser.add_argument("--data", help="folder of .hrec recordings (default: simulate the paper's protocol)")
    add_out(parser, "folder for sweep.json and the figures", default="report")
    parser.add_argument("--pads", default="all")
    parser.add_argument("--K", type=int, default=PAPER_MODEL["K"], help="K kept fixed while W and T vary")
    parser.add_argument("--W", type=int, default=PAPER_MODEL["W"], help="W kept fixed while K and T vary")
    parser.add_argument("--T", type=int, default=PAPER_MODEL["T"], help="T kept fixed while K and W vary")
    parser.add_argument("--K-values", type=_ints, default=FULL_K, help="e.g. 2,4,6,8,10,12,15,20,30")
    parser.add_argument("--W-values", type=_ints, default=FULL_W)
    parser.add_argument("--T-values", type=_ints, default=FULL_T)
    parser.add_argument("--kernels", default="rbf,linear", help="comma-separated: rbf, linear")
    parser.add_argument("--mode", choices=("config1", "loso"), default="config1",
                        help="config1: pooled 80/20 over --repeats seeds; loso: leave one subject out")
    parser.add_argument("--repeats", type=positive_int, default=3, help="seeds per point in config1 mode")
    parser.add_argument("--per-pad", action="store_true")
    parser.add_argument("--fraction", type=trigger_level, default=PAPER_FRACTION,
                        help=f"threshold trigger level, fraction of full scale (default: the paper's {PAPER_FRACTION})")
    add_seed(parser)
    add_json(parser, "the sweep rows")
    add_quiet(parser)


def main(args: argparse.Namespace) -> int:
    kernels = [k.strip() for k in args.kernels.split(",") if k.strip()]
    bad = [k for k in kernels if k not in ("rbf", "linear")]
    if bad or not kernels:
        raise HandoverError(f"unknown kernel {bad[0] if bad else '(none)'!r}; use rbf and/or linear")
    try:
        return _run(args, kernels)
    except (OSError, ValueError) as exc:  # an unreadable folder or data that cannot sweep: the user's to fix
        raise HandoverError(str(exc)) from exc


def _run(args, kernels: list[str]) -> int:
    from firmware_io.commands.options import progress_to
    from trainer import report
    from trainer.pipeline import load_or_simulate, progress_bar
    from trainer.sweeps import run_sweeps

    t0 = time.perf_counter()
    out = out_folder(args.out)
    say = progress_to(args.quiet)
    recordings, _names, source, synthetic = load_or_simulate([args.data] if args.data else None, args.seed, say)
    base = {"K": args.K, "W": args.W, "T": args.T, "seed": args.seed, "per_pad": args.per_pad}
    n = len(kernels) * (len(args.K_values) + len(args.W_values) + len(args.T_values))
    seeds = tuple(range(args.seed, args.seed + args.repeats))
    result = run_sweeps(recordings, base, args.K_values, args.W_values, args.T_values, kernels, args.pads,
                        args.fraction, mode=args.mode, seeds=seeds, progress=progress_bar(args.quiet, "sweep", n))
    result.update(synthetic=synthetic, data=source, pads=args.pads, seconds=round(time.perf_counter() - t0, 1))
    (out / "sweep.json").write_text(json.dumps(result, indent=1, default=report._json_default))
    for param in ("K", "W", "T"):
        rows = [r for r in result["rows"] if r["param"] == param]
        if rows:
            fixed = ", ".join(f"{p}={base[p]}" for p in ("K", "W", "T") if p != param)
            report.plot_sweep(rows, param, fixed, out / f"sweep_{param}.png", synthetic)
    say(f"sweep written to {out / 'sweep.json'} ({result['seconds']:.0f} s)")
    if args.json:
        print(json.dumps(result, default=report._json_default))
    return 0
