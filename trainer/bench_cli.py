"""``handover bench pareto|latency|throughput|hostile|streams|all|soak|decode|inference|ros2|early``: the
benchmarks (trainer/bench/, their one home), results in results/.

Each benchmark writes ``<out>/<name>.json`` and ``.md`` (+ ``.png`` where a plot fits) with
the machine it ran on and the command that reproduces it. ``--json`` prints the headline
figures (onnx_p50_us, onnx_p99_us, sklearn_p50_us, speedup_vs_sklearn, e2e_p99_us,
replay_frames_per_s, rss_mb, ... where they apply). Models are trained on the simulated hand
(synthetic data). Run them on a machine as quiet as you can get: timings share the CPU.
"""

from __future__ import annotations

import argparse
import json

from firmware_io.errors import fail

__all__ = ["add_arguments", "main"]

COMMAND = "bench"
BENCHMARKS = ("pareto", "latency", "throughput", "hostile", "streams")
"""What ``all`` runs (``./dev bench``)."""
SINGLE = ("soak", "decode", "inference", "ros2", "early", "streams_own")
"""Run only by name: soak runs for hours; decode pins itself to one core; inference compares with
scikit-learn on a small BoW model; ros2 needs a sourced ROS 2; early needs aeon (the bench extra);
streams_own records scripted subjects and trains on them (after streams, whose results it adds to)."""
HEADLINE = ("hours", "frames_expected", "frames_lost_outside_injected_faults", "faults_injected", "faults_recovered",
            "max_recovery_s", "events_lost", "rss_growth_mb", "watchdog_would_fire",
            "watchdog_would_fire_while_healthy", "onnx_p50_us", "onnx_p99_us", "sklearn_p50_us", "speedup_vs_sklearn",
            "default_on_front", "onnx_p50_us_all_pads", "numpy_over_onnx_p50", "sklearn_over_onnx_p50", "daemon_p999_us",
            "paced_over_back_to_back",
            "e2e_p50_us", "e2e_p99_us", "e2e_p999_us", "e2e_max_us", "e2e_p999_us_load", "e2e_load_p99_us",
            "replay_frames_per_s", "rss_mb", "cpu_share", "startup_to_ready_s", "swap_s", "hostile_failures",
            "default_setting", "demo_events_correct_fraction", "demo_events_outside", "sim_event_f1", "real_idle_hours",
            "real_idle_false_events_per_hour", "continuous_hold_recall", "continuous_events_correct_fraction",
            "onset_to_report_median_frames", "rle_frames_per_s", "raw_frames_per_s", "speedup_median",
            "ros2_event_p99_us", "early_default_hm_mean", "own_model_idle_false_events_per_hour",
            "own_model_demo_events_correct_fraction", "own_model_real_idle_false_events_per_hour")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("which", metavar="BENCHMARK", choices=(*BENCHMARKS, "all", *SINGLE),
                        help=f"which benchmark to run ('all' = {', '.join(BENCHMARKS)}; {', '.join(SINGLE)} run only "
                        "by name)")
    parser.add_argument("--out", default=None, help="folder for <name>.json/.md/.png (default results; with "
                        "--quick handover-bench-quick-USER in the system's temp folder, so a smoke test never "
                        "overwrites the committed results)")
    parser.add_argument("--quick", action="store_true", help="tiny sizes and short runs (smoke test, not a measurement)")
    parser.add_argument("--json", action="store_true", help="print the headline figures as JSON on stdout")
    parser.add_argument("--load", action="store_true", help="latency: also measure with two busy-loop processes")
    parser.add_argument("--duration", type=float, default=None,
                        help="latency: seconds of the 32 Hz end-to-end run (default 120, --quick 3)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulated protocol (default 0)")
    parser.add_argument("--hours", type=float, default=None,
                        help="soak: hours against the emulator with faults injected (default 1, --quick 0.01)")
    parser.add_argument("--quiet", action="store_true", help="no progress messages on stderr")
    parser.add_argument("--frames", type=int, default=None, help="decode: frames to encode and decode (default 4000)")
    parser.add_argument("--repeats", type=int, default=None,
                        help="decode: timed runs (default 7); inference: graph calls (default 5000)")
    parser.add_argument("--synthetic", action="store_true", help="decode: skip the real recordings")
    parser.add_argument("--model", help="inference: an exported .onnx with its .joblib beside it (default: train one)")
    parser.add_argument("--seconds", type=float, default=None, help="ros2: seconds of streaming (default 60)")
    parser.add_argument("--speed", type=float, default=None, help="ros2: sim:// speed-up (default 16)")
    parser.add_argument("--pad-rate", type=float, default=None, help="ros2: [ros2] pad_rate_hz (default 32)")
    parser.add_argument("--rerender", action="store_true",
                        help="pareto: re-mark the default and rewrite .md/.png from OUT/pareto.json (no measuring)")


def main(args: argparse.Namespace) -> int:
    from trainer.bench.common import default_out, out_problem, progress

    if args.duration is not None and args.duration <= 0:
        return fail(COMMAND, f"--duration must be positive, got {args.duration}")
    if args.hours is not None and not 0 < args.hours <= 168:
        return fail(COMMAND, f"--hours must be in (0, 168], got {args.hours}")
    for flag, value in (("--frames", args.frames), ("--repeats", args.repeats), ("--seconds", args.seconds),
                        ("--speed", args.speed), ("--pad-rate", args.pad_rate)):
        if value is not None and not value > 0:
            return fail(COMMAND, f"{flag} must be positive, got {value}")
    if args.out is None:
        args.out = default_out(args.quick)
    if problem := out_problem(args.out):
        return fail(COMMAND, problem)
    args.say = progress(args.quiet)
    which = BENCHMARKS if args.which == "all" else (args.which,)
    figures: dict = {}
    for name in which:
        module = __import__(f"trainer.bench.{name}", fromlist=["run"])
        try:
            result = module.rerender(args.out) if args.rerender and name == "pareto" else module.run(args)
        except (OSError, ValueError, RuntimeError) as exc:
            return fail(COMMAND, f"{name}: {exc}")
        figures[name] = {k: result[k] for k in HEADLINE if k in result}
        args.say(f"{name}: wrote {args.out}/{name}.json and .md " + json.dumps(figures[name]))
    if args.json:
        flat = {k: v for f in figures.values() for k, v in f.items()}
        print(json.dumps(flat if len(figures) > 1 else next(iter(figures.values()))))
    return 0
