"""``handover export MODEL.joblib --out model.onnx``: one ONNX graph from a trained model
(trainer.trained_file reads and exports it)."""

from __future__ import annotations

import argparse
from pathlib import Path

from firmware_io.errors import HandoverError
from trainer.trained_file import export_trained

__all__ = ["add_arguments", "main"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", help="trained model (.joblib written by handover train)")
    parser.add_argument("--out", help="ONNX file to write (default: MODEL with suffix .onnx)")
    parser.add_argument("--pads", help="pads the model reads (default: as stored by handover train; for a bare "
                        "estimator file: distal); e.g. distal, all, 1,3,5")
    parser.add_argument("--fold-derivative", action="store_true",
                        help="fold the time derivative into the codeword kernel (one node less, less accurate)")


def main(args: argparse.Namespace) -> int:
    from firmware_io.errors import DeviceFailure
    from runtime.commands.inspect_cli import feature_summary
    from runtime.model import ModelContractError, load_model

    out = Path(args.out) if args.out else Path(args.model).with_suffix(".onnx")
    try:
        path = export_trained(args.model, out, args.pads, args.fold_derivative)
    except OSError as exc:  # the file given: the user's to fix (an ExportError says so itself)
        raise HandoverError(str(exc)) from exc
    try:
        model = load_model(path)
    except ModelContractError as exc:  # the export itself broke the contract: not the user's input
        raise DeviceFailure(f"{path}: the exported graph breaks the model contract ({exc})") from exc
    print(f"wrote {path}: id {model.model_id}, {model.n_nodes} nodes, {model.n_bytes} bytes, "
          f"classes {', '.join(model.meta.classes)}, T={model.meta.T}, {feature_summary(model)}")
    return 0
