"""Tiny but valid handover model files for runtime tests (built with the onnx helper API).

The graph honours the model contract (input ``frames`` [N, T, C], outputs ``label`` and
``scores``, the ``handover`` metadata) but its "classifier" is a toy: the scores are
``mean(frames) * weights + bias``, so a test can steer the decision through the input.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

CLASSES = ("pull", "push", "hold", "bump")


def tiny_model_bytes(
    classes: tuple[str, ...] = CLASSES,
    pads: tuple[int, ...] = (1, 3, 5),
    pad_sizes: tuple[int, ...] = (78, 78, 78),
    T: int = 15,
    weights: tuple[float, ...] | None = None,
    bias: tuple[float, ...] | None = None,
    dormant_class: str | None = None,
    trigger_fraction: float = 0.15,
    tag: str = "",
    trigger: dict | None = None,
    extra: dict | None = None,
) -> bytes:
    import onnx
    from onnx import TensorProto, helper

    n_classes = len(classes)
    C = int(sum(pad_sizes))
    w = np.asarray(weights if weights is not None else [0.0] * n_classes, dtype=np.float32).reshape(1, n_classes)
    b = np.asarray(bias if bias is not None else [1.0] + [0.0] * (n_classes - 1), dtype=np.float32)
    nodes = [
        helper.make_node("ReduceMean", ["frames", "axes"], ["mean3"], keepdims=1),
        helper.make_node("Reshape", ["mean3", "shape"], ["mean"]),
        helper.make_node("MatMul", ["mean", "w"], ["prod"]),
        helper.make_node("Add", ["prod", "b"], ["scores"]),
        helper.make_node("ArgMax", ["scores"], ["label"], axis=1, keepdims=0),
    ]
    inits = [
        helper.make_tensor("axes", TensorProto.INT64, [2], [1, 2]),
        helper.make_tensor("shape", TensorProto.INT64, [2], [-1, 1]),
        helper.make_tensor("w", TensorProto.FLOAT, [1, n_classes], w.ravel().tolist()),
        helper.make_tensor("b", TensorProto.FLOAT, [n_classes], b.tolist()),
    ]
    graph = helper.make_graph(
        nodes,
        "tiny",
        [helper.make_tensor_value_info("frames", TensorProto.FLOAT, ["N", T, C])],
        [
            helper.make_tensor_value_info("label", TensorProto.INT64, ["N"]),
            helper.make_tensor_value_info("scores", TensorProto.FLOAT, ["N", n_classes]),
        ],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)], ir_version=8)
    meta = {
        "schema_version": 1,
        "classes": list(classes),
        "T": T,
        "W": 7,
        "K": 10,
        "pads": list(pads),
        "n_channels": C,
        "pad_sizes": list(pad_sizes),
        "fullscale": 4095.0,
        "trigger": {"fraction": trigger_fraction, **(trigger or {})},
        "sample_rate_hz": 32.0,
        "score": "ovr",
        "dormant_class": dormant_class,
        "training": {"data_fingerprint": "synthetic-test" + tag, "n_trials": 0, "project_version": "test",
                     "date": "2026-01-01"},
        "evaluation": {},
        **(extra or {}),
    }
    helper.set_model_props(model, {"handover": json.dumps(meta)})
    onnx.checker.check_model(model)
    return model.SerializeToString()


def write_model(folder: Path, name: str, data: bytes, mode: int = 0o644, mtime: float | None = None) -> Path:
    """The documented safe way: write a dot-temp file, chmod, rename into place."""
    folder = Path(folder)
    tmp = folder / f".{name}.tmp"
    tmp.write_bytes(data)
    os.chmod(tmp, mode)
    if mtime is not None:
        os.utime(tmp, (mtime, mtime))
    final = folder / name
    os.replace(tmp, final)
    return final


def dormant_then_plain(root: Path) -> Path:
    """``root``/models with ``stream.onnx`` (a dormant class, dropped a minute ago) and ``plain.onnx``
    (the four actions, dropped last): what a switch to ``scene.mode = "continuous"`` meets."""
    import time

    folder = Path(root) / "models"
    folder.mkdir()
    dormant = tiny_model_bytes(classes=(*CLASSES, "dormant"), dormant_class="dormant")
    write_model(folder, "stream.onnx", dormant, mtime=time.time() - 60)
    write_model(folder, "plain.onnx", tiny_model_bytes(tag="plain"))
    return folder
