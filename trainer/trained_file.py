"""A trained-model file (the joblib ``handover train`` keeps) read back and exported to one ONNX graph.

The joblib holds ``{"model": estimator, "metadata": {...}}`` or a bare fitted estimator, which carries no
pads (default distal). The ``.joblib`` stays next to the ``.onnx`` as ``handover verify``'s float64
reference; its sha256 in the graph ties the pair.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

from firmware_io.errors import HandoverError

__all__ = ["export_trained", "load_trained"]


class ExportError(HandoverError, ValueError):
    """A trained-model file or option that cannot be exported."""


def load_trained(path: str | Path, with_early: bool = False):
    """(fitted BowSVC/FlatSVC, metadata dict) from a joblib file; ExportError names what is wrong.
    ``with_early``: also the early heads train saved beside the model (``trainer.early.EarlyHeads`` or None)."""
    import joblib

    path = Path(path)
    beside = path.parent / "model.joblib" if path.suffix in (".onnx", ".joblib") else Path("report/model.joblib")
    give = f"give the .joblib that train wrote (e.g. {beside})"
    try:
        with path.open("rb") as f:
            head = f.read(16)
    except FileNotFoundError:
        raise ExportError(f"{path}: no such file; {give}") from None
    except OSError as exc:
        raise ExportError(f"{path}: cannot read ({exc.strerror or exc}); {give}") from None
    kind = _other_kind(path, head)
    if kind:
        raise ExportError(f"{path}: this is {kind}, not a trained model; {give}")
    try:
        obj = joblib.load(path)
    except Exception as exc:  # joblib/pickle raise many types for a broken file
        raise ExportError(f"{path}: not a readable joblib file ({type(exc).__name__}: {exc}); {give}") from exc
    metadata: dict = {}
    early = None
    if isinstance(obj, dict) and "model" in obj:
        metadata = dict(obj.get("metadata") or {})
        early = obj.get("early")  # trainer.early.EarlyHeads, when train fitted them
        obj = obj["model"]
    if not all(hasattr(obj, a) for a in ("svm_", "classes_")):
        raise ExportError(f"{path}: holds a {type(obj).__name__}, not a fitted BowSVC or FlatSVC")
    return (obj, metadata, early) if with_early else (obj, metadata)


def _other_kind(path: Path, head: bytes) -> str | None:
    """What a file given to export is instead of a joblib: an ONNX model (export's own output) or a
    recording; None when it may be a joblib (a pickle starts with 0x80, a compressed one otherwise)."""
    if path.suffix == ".hrec":  # a zip of arrays
        return "a recording (train on it first: handover train --data FOLDER)"
    if path.suffix == ".onnx" or head.startswith(b"\x08"):  # ONNX: field 1 (ir_version), a varint
        return "an ONNX model (what export writes)"
    return None


def export_trained(source: str | Path, out: str | Path, pads: str | None = None, fold_derivative: bool = False) -> Path:
    """Export a trained-model file; fills pads and training provenance it does not carry."""
    from firmware_io.layout import SensorLayout
    from trainer.onnx_export import export_onnx, model_shape

    source = Path(source)
    model, metadata, early = load_trained(source, with_early=True)
    _, n_channels = model_shape(model)
    if pads is not None or "pads" not in metadata:
        layout = SensorLayout.sdh2()
        try:
            idx = layout.pads(pads or "distal")
        except ValueError as exc:
            raise ExportError(str(exc)) from None
        sizes = layout.pad_sizes(idx)
        if sum(sizes) != n_channels:
            raise ExportError(
                f"pads {pads or 'distal'} have {sum(sizes)} taxels but the model was trained on {n_channels}; pass --pads"
            )
        metadata["pads"], metadata["pad_sizes"] = list(idx), list(sizes)
    training = {"data_fingerprint": "unknown", "n_trials": None, **metadata.get("training", {})}
    metadata["training"] = training
    out = Path(out)
    ref_name = os.path.relpath(source.resolve(), out.resolve().parent)
    metadata["reference"] = {"file": ref_name, "sha256": hashlib.sha256(source.read_bytes()).hexdigest()}
    try:
        return export_onnx(model, out, metadata, fold_derivative=fold_derivative, early=early)
    except ValueError as exc:
        raise ExportError(str(exc)) from exc
