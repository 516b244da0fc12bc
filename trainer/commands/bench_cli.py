"""``handover bench latency|throughput|inference``: what a lab measures on its own robot PC.

Each writes ``<out>/<name>.json`` and ``.md`` (+ ``.png`` where a plot fits) with the machine it
ran on and the command that reproduces it; ``--json`` prints the headline figures. Models are
trained on the simulated hand (synthetic data). Run on a machine as quiet as you can get: timings
share the CPU. The studies behind results/ (hostile, soak, streams, pareto, ...) are the
checkout's ``./dev bench`` (benchmarks/, not installed), which runs these three as well.
"""

from __future__ import annotations

import argparse
import importlib
import json
from collections.abc import Sequence

from firmware_io.commands.options import add_json, add_out, add_quiet, add_seed, positive_float, positive_int
from firmware_io.errors import HandoverError
from trainer.measure import PRODUCT_BENCHES

__all__ = ["add_arguments", "main", "run"]

COMMAND = "bench"
BENCHMARKS = PRODUCT_BENCHES
HEADLINE = ("onnx_p50_us", "onnx_p99_us", "sklearn_p50_us", "speedup_vs_sklearn", "onnx_p50_us_all_pads",
            "numpy_over_onnx_p50", "sklearn_over_onnx_p50", "daemon_p999_us", "paced_over_back_to_back", "shadow_p999_ratio",
            "shadow_capture_p999_ratio",
            "e2e_p50_us", "e2e_p99_us", "e2e_p999_us", "e2e_max_us", "e2e_p999_us_load", "e2e_load_p99_us",
            "replay_frames_per_s", "rss_mb", "cpu_share", "startup_to_ready_s", "swap_s", "speedup_median")
"""The figures ``--json`` prints, where a benchmark has them."""


def add_arguments(parser: argparse.ArgumentParser, choices: Sequence[str] = BENCHMARKS) -> None:
    """The options every benchmark runner shares (``./dev bench`` adds its own on top)."""
    parser.add_argument("which", metavar="BENCHMARK", choices=choices, help="which benchmark to run: "
                        + ", ".join(choices))
    add_out(parser, "folder for <name>.json/.md/.png (default results; with --quick handover-bench-quick-USER in "
            "the system's temp folder, so a smoke test never overwrites the committed results)")
    parser.add_argument("--quick", action="store_true", help="tiny sizes and short runs (smoke test, not a measurement)")
    add_json(parser, "the headline figures")
    parser.add_argument("--load", action="store_true", help="latency: also measure with two busy-loop processes")
    parser.add_argument("--duration", type=positive_float, default=None,
                        help="latency: seconds of the 32 Hz end-to-end run (default 120, --quick 3)")
    add_seed(parser, help="seed of the simulated protocol")
    add_quiet(parser)
    parser.add_argument("--repeats", type=positive_int, default=None,
                        help="inference: graph calls (default 5000); decode (./dev bench): timed runs (default 7)")
    parser.add_argument("--model", help="inference: an exported .onnx with its .joblib beside it (default: train one)")


def main(args: argparse.Namespace) -> int:
    return run(args, {name: f"trainer.bench.{name}" for name in BENCHMARKS}, HEADLINE)


def run(args: argparse.Namespace, modules: dict[str, str], headline: Sequence[str]) -> int:
    """Run ``args.which`` (a list of names, or one) from ``modules`` (name -> module with ``run(args)``)."""
    from firmware_io.commands.options import out_folder, progress_to
    from trainer.measure import default_out

    if args.out is None:
        args.out = default_out(args.quick)
    out_folder(args.out)
    args.say = progress_to(args.quiet)
    which = (args.which,) if isinstance(args.which, str) else args.which
    figures: dict = {}
    for name in which:
        module = importlib.import_module(modules[name])
        try:
            rerender = getattr(args, "rerender", False) and hasattr(module, "rerender")
            result = module.rerender(args.out) if rerender else module.run(args)
        except (OSError, ValueError, RuntimeError) as exc:
            raise HandoverError(f"{name}: {exc}") from exc
        figures[name] = {k: result[k] for k in headline if k in result}
        args.say(f"{name}: wrote {args.out}/{name}.json and .md " + json.dumps(figures[name]))
    if args.json:
        flat = {k: v for f in figures.values() for k, v in f.items()}
        print(json.dumps(flat if len(figures) > 1 else next(iter(figures.values()))))
    return 0
