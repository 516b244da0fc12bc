"""``./dev bench compare``: the paper's BoW + SVM against richer options and reference classifiers,
side by side on the simulated protocol (synthetic) and the real recordings; writes
``results/compare.{json,md,png}`` with the machine and the reproducing command."""

from __future__ import annotations

import argparse
import json
import shlex
from pathlib import Path

from firmware_io.commands.options import add_quiet, progress_to
from firmware_io.errors import HandoverError
from trainer.shared_data import default_data_dir

__all__ = ["add_arguments", "main"]

COMMAND = "compare"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true", help="2 simulated subjects, fewer models and repeats (a smoke run)")
    parser.add_argument("--json", action="store_true", help="print the results as JSON on stdout")
    parser.add_argument("--out", default=None, help="folder for compare.json/.md/.png (default results; with "
                        "--quick handover-bench-quick-USER in the system's temp folder, so a smoke run never overwrites "
                        "the committed results)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--n-jobs", type=int, default=2, help="parallel folds (at most 2)")
    parser.add_argument("--data", help="shared data folder holding sdh2-dsa/ (default $HANDOVER_SHARED_DATA or "
                        "../shared/data)")
    parser.add_argument("--no-real", action="store_true", help="simulated protocol only")
    parser.add_argument("--no-minirocket", action="store_true", help="leave out aeon's MiniRocket")
    add_quiet(parser)


def command_line(args: argparse.Namespace) -> str:
    parts = ["./dev", "bench", "compare"]
    for flag, on in (("--quick", args.quick), ("--no-real", args.no_real), ("--no-minirocket", args.no_minirocket)):
        if on:
            parts.append(flag)
    from trainer.measure import out_option

    parts += ["--seed", str(args.seed), "--n-jobs", str(args.n_jobs), *out_option(args.out, args.quick)]
    if args.data:
        parts += ["--data", str(args.data)]
    return shlex.join(parts)


def main(args: argparse.Namespace) -> int:
    from firmware_io.commands.options import out_folder
    from trainer.measure import default_out

    if args.out is None:
        args.out = default_out(args.quick)
    out_folder(args.out)
    if not 1 <= args.n_jobs <= 2:
        raise HandoverError(f"--n-jobs must be 1 or 2 (the machine has 2 cores), got {args.n_jobs}")
    minirocket = not args.no_minirocket
    if minirocket:
        import importlib.util

        if importlib.util.find_spec("aeon") is None:
            raise HandoverError("MiniRocket needs the Python package 'aeon': in a checkout `./dev bench --help` "
                         "installs it into .venv (elsewhere pip install 'tactile-handover[bench]'), or pass "
                         "--no-minirocket")
    from benchmarks import compare
    from trainer.measure import load_average, write_results

    say = progress_to(args.quiet)
    data_dir = None if args.no_real else Path(args.data) if args.data else default_data_dir()
    if args.data and not Path(args.data).is_dir():
        raise HandoverError(f"--data {args.data}: no such folder")
    try:
        res = compare.run(args.quick, args.seed, args.n_jobs, data_dir, minirocket, say)
    except (OSError, ValueError) as exc:
        raise HandoverError(f"{type(exc).__name__}: {exc}") from exc
    res["command"] = command_line(args)
    res["load_after"] = load_average()
    out = Path(args.out)
    try:
        compare.plot(res, out / "compare.png")
        path = write_results(out, "compare", res, compare.markdown(res))
    except OSError as exc:
        raise HandoverError(f"--out {out}: cannot write the results ({exc.strerror or exc})") from exc
    say(f"written {path}, {out / 'compare.md'}, {out / 'compare.png'}")
    if args.json:
        print(json.dumps(res, default=str))
    return 0
