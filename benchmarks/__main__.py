"""``./dev bench [NAME] [options]`` (``python -m benchmarks`` from the checkout): the benchmarks and
studies behind the committed results/.

Without NAME it runs ``all``: pareto, latency, throughput, hostile, streams. latency, throughput and
inference are the product's ``handover bench`` (trainer/bench/, what a lab runs on its robot); the
rest live here. ``compare``, ``dormant`` and the studies take their own options (``./dev bench
compare --help``).
"""

from __future__ import annotations

import argparse
import importlib
import sys

from firmware_io.commands.options import positive_float, positive_int
from firmware_io.errors import INTERRUPTED, HandoverError
from runtime.cli import HelpFormatter, OneLineParser
from trainer.commands import bench_cli

ALL = ("pareto", "latency", "throughput", "hostile", "streams")
"""What ``all`` (``./dev bench``) runs."""
SINGLE = ("soak", "decode", "inference", "ros2", "early", "streams_own", "field", "own_prior")
"""Run only by name: soak runs for hours; decode pins itself to one core; inference compares with
scikit-learn on a small BoW model; ros2 needs a sourced ROS 2; early needs aeon (the bench extra);
streams_own records scripted subjects and trains on them (after streams, whose results it adds to);
field plays three emulated days to daemons and trains three models (minutes); own_prior records and trains
as a lab does, with and without the product's prior (about half an hour)."""
COMMANDS = {"compare": "benchmarks.compare_cli", "dormant": "benchmarks.dormant_cli"}
"""Studies with a command of their own (``add_arguments``/``main``): they compare methods on the
simulated hand and the project's recordings for results/, not what a lab runs on its robot."""
STUDIES = ("lab_shift", "ramp_windows", "realism_plot")
"""benchmarks/studies/: questions of past work, each with its own ``main(argv)``."""
HEADLINE = (*bench_cli.HEADLINE, "hours", "frames_expected", "frames_lost_outside_injected_faults",
            "faults_injected", "faults_recovered", "max_recovery_s", "events_lost", "rss_growth_mb",
            "watchdog_would_fire", "watchdog_would_fire_while_healthy", "default_on_front", "hostile_failures",
            "default_setting", "demo_events_correct_fraction", "demo_events_outside", "sim_event_f1",
            "real_idle_hours", "real_idle_false_events_per_hour", "continuous_hold_recall",
            "continuous_events_correct_fraction", "onset_to_report_median_frames", "rle_frames_per_s",
            "raw_frames_per_s", "ros2_event_p99_us", "early_default_hm_mean",
            "own_model_idle_false_events_per_hour", "own_model_demo_events_correct_fraction",
            "own_model_real_idle_false_events_per_hour")
MODULES = {name: (f"trainer.bench.{name}" if name in bench_cli.BENCHMARKS else f"benchmarks.{name}")
           for name in (*ALL, *SINGLE)}


def parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="./dev bench", description=__doc__.split("\n\n")[0], formatter_class=HelpFormatter,
                                epilog=f"also: {', '.join(COMMANDS)} and the studies {', '.join(STUDIES)}, each "
                                "with its own options")
    bench_cli.add_arguments(p, (*ALL, "all", *SINGLE))
    p.add_argument("--hours", type=positive_float, default=None,
                   help="soak: hours against the emulator with faults injected (default 1, --quick 0.01)")
    p.add_argument("--frames", type=positive_int, default=None, help="decode: frames to encode and decode (default 4000)")
    p.add_argument("--synthetic", action="store_true", help="decode: skip the real recordings")
    p.add_argument("--seconds", type=positive_float, default=None, help="ros2: seconds of streaming (default 60)")
    p.add_argument("--speed", type=positive_float, default=None, help="ros2: sim:// speed-up (default 16)")
    p.add_argument("--pad-rate", type=positive_float, default=None, help="ros2: [ros2] pad_rate_hz (default 32)")
    p.add_argument("--rerender", action="store_true",
                   help="pareto: re-mark the default and rewrite .md/.png from OUT/pareto.json (no measuring)")
    return p


def main(argv: list[str]) -> int:
    try:
        return _run(argv)
    except HandoverError as exc:  # as handover's main does for its commands
        print(f"./dev bench {argv[0] if argv else 'all'}: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"handover {bench_cli.COMMAND}: interrupted", file=sys.stderr)
        return INTERRUPTED


def _run(argv: list[str]) -> int:
    name = argv[0] if argv else "all"
    if name in COMMANDS:
        module = importlib.import_module(COMMANDS[name])
        sub = OneLineParser(prog=f"./dev bench {name}", description=module.__doc__.split("\n\n")[0],
                                      formatter_class=HelpFormatter)
        module.add_arguments(sub)
        return module.main(sub.parse_args(argv[1:]))
    if name in STUDIES:
        return importlib.import_module(f"benchmarks.studies.{name}").main(argv[1:])
    args = parser().parse_args(argv or ["all"])
    if args.hours is not None and not args.hours <= 168:
        raise HandoverError(f"--hours must be in (0, 168], got {args.hours}")
    args.which = ALL if args.which == "all" else args.which
    return bench_cli.run(args, MODULES, HEADLINE)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
