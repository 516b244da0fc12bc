"""The ``handover`` command: one entry point, subcommands imported only when chosen.

Each subcommand lives in its own module with ``add_arguments(parser)`` and
``main(args) -> int``. Only the chosen module is imported, so ``handover run`` never
pulls in scikit-learn or matplotlib.
"""

from __future__ import annotations

import argparse
import importlib
import sys

# name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("trainer.demo_cli", "end-to-end demo on the simulated hand: simulate, train, export, emulate, detect"),
    "simulate": ("firmware_io.simulate_cli", "write the paper's protocol (or a scripted session) from the simulated hand"),
    "import": ("firmware_io.import_cli", "convert DSA-Konqueror .dsa files or ROS bags to recordings"),
    "train": ("trainer.train_cli", "train BoW + SVM, evaluate as in the paper, write a report and the ONNX model"),
    "sweep": ("trainer.sweep_cli", "accuracy against K, W, T and kernel (the paper's sweeps)"),
    "export": ("trainer.export_cli", "export a trained model to one ONNX graph"),
    "verify": ("trainer.verify_cli", "compare an ONNX model with the float64 reference, with stress cases"),
    "inspect": ("runtime.inspect_cli", "print a model card from an ONNX model's metadata"),
    "emulate": ("firmware_io.emulate_cli", "serve an emulated DSACON32m over TCP or a pseudo-terminal"),
    "dump": ("firmware_io.dump_cli", "print frames from any device URL (rate, per-pad sums, errors)"),
    "run": ("runtime.daemon_cli", "the detection daemon (systemd service)"),
    "record": ("firmware_io.record_cli", "record a subject session following the paper's protocol"),
    "plot": ("trainer.plot_cli", "plot a trial of a recording"),
    "bench": ("trainer.bench_cli", "benchmarks: pareto, latency, throughput, hostile, streams (events in live streams)"),
    "compare": ("trainer.compare_cli", "side by side: paper BoW, richer options, baseline, flattened SVM, MiniRocket (accuracy + latency)"),
    "dormant": ("trainer.dormant_cli", "dormant class + continuous mode vs the threshold trigger on long simulated streams"),
}


def _usage() -> str:
    width = max(len(n) for n in COMMANDS)
    lines = ["usage: handover COMMAND [options]", "", "commands:"]
    for name, (module, help_text) in COMMANDS.items():
        if importlib.util.find_spec(module) is not None:
            lines.append(f"  {name:<{width}}  {help_text}")
    lines.append("")
    lines.append("handover COMMAND --help shows the options of one command.")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(_usage())
        return 0
    if argv[0] == "--version":
        from runtime import __version__

        print(__version__)
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"handover: unknown command {name!r}\n\n{_usage()}", file=sys.stderr)
        return 2
    module_name, help_text = COMMANDS[name]
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        missing = exc.name or "?"
        hint = "pip install 'tactile-handover[train]'" if missing.split(".")[0] in _TRAIN_PACKAGES else ""
        print(f"handover {name}: needs the Python package {missing!r} which is not installed. {hint}".rstrip(),
              file=sys.stderr)
        return 2
    parser = argparse.ArgumentParser(prog=f"handover {name}", description=help_text)
    module.add_arguments(parser)
    args = parser.parse_args(rest)
    try:
        return int(module.main(args) or 0)
    except KeyboardInterrupt:
        print(f"handover {name}: interrupted", file=sys.stderr)
        return 130


_TRAIN_PACKAGES = {"sklearn", "skl2onnx", "onnx", "matplotlib", "tqdm", "joblib", "rosbags"}


if __name__ == "__main__":
    sys.exit(main())
