"""Hostile model files: valid by every static check of the contract, wrong or slow at run time.

Built with the ``onnx`` helper API from a toy classifier (scores = mean(frames) * w + b) so
that tests and ``./dev bench hostile`` attack the daemon with the same files:

- ``label_out_of_range``: label + 100 whenever any taxel is non-zero (right on all-zero input);
- ``nan_scores`` / ``inf_scores``: NaN / infinite scores whenever any taxel is non-zero;
- ``slow``: a chain of ``n_nodes`` element-wise nodes, so one decision takes milliseconds;
- ``hang``: an ONNX ``Loop`` whose trip count becomes 2e9 on a window of real frames;
- ``mutations``: byte-level mutations of a valid file.
"""

from __future__ import annotations

import json
import os
import random
from collections.abc import Iterator
from pathlib import Path

CLASSES = ("pull", "push", "hold", "bump")
PADS = (1, 3, 5)
PAD_SIZES = (78, 78, 78)
T = 15


def write_model(folder: Path, name: str, data: bytes, mtime: float | None = None) -> Path:
    """Drop a model file the safe way (a temporary name, then a rename), mode 644."""
    tmp = folder / f".{name}.tmp"
    tmp.write_bytes(data)
    os.chmod(tmp, 0o644)
    if mtime is not None:
        os.utime(tmp, (mtime, mtime))
    os.replace(tmp, folder / name)
    return folder / name


def metadata(tag: str = "") -> dict:
    """The ``handover`` metadata of a distal-pads model (matches the daemon's default scene):
    ``trainer.model_meta``'s defaults plus the keys a graph built here determines."""
    from trainer.model_meta import file_metadata

    return {
        "schema_version": 1, "classes": list(CLASSES), "T": T, "W": 7, "K": 10,
        "n_channels": int(sum(PAD_SIZES)), "score": "ovr",
        **file_metadata(pads=PADS, pad_sizes=PAD_SIZES, training={
            "data_fingerprint": "hostile" + tag, "n_trials": 0, "project_version": "test", "date": "2026-01-01"}),
    }


def _model(kind: str, n_nodes: int = 0, bias_class: int = 0, tag: str = "", peak: float | None = None) -> bytes:
    """``peak``: the attack fires only on windows whose largest value is exactly this (a sleeper
    that passes any warm-up); None: on any non-zero window."""
    import onnx
    from onnx import TensorProto, helper

    n_classes, C = len(CLASSES), int(sum(PAD_SIZES))
    bias = [0.0] * n_classes
    bias[bias_class] = 1.0
    nodes = [
        helper.make_node("ReduceMean", ["frames", "axes"], ["mean3"], keepdims=1),
        helper.make_node("Reshape", ["mean3", "shape"], ["mean"]),
        helper.make_node("MatMul", ["mean", "w"], ["prod"]),
        helper.make_node("Add", ["prod", "b"], ["raw"]),
        helper.make_node("ReduceMax", ["frames"], ["peak"], keepdims=0),
        helper.make_node("Greater" if peak is None else "Equal", ["peak", "zero" if peak is None else "magic"],
                         ["pressed"]),
    ]
    inits = [
        helper.make_tensor("axes", TensorProto.INT64, [2], [1, 2]),
        helper.make_tensor("shape", TensorProto.INT64, [2], [-1, 1]),
        helper.make_tensor("w", TensorProto.FLOAT, [1, n_classes], [0.0] * n_classes),
        helper.make_tensor("b", TensorProto.FLOAT, [n_classes], bias),
        helper.make_tensor("zero", TensorProto.FLOAT, [], [0.0]),
        helper.make_tensor("hundred", TensorProto.INT64, [], [100]),
        helper.make_tensor("nolabel", TensorProto.INT64, [], [0]),
        helper.make_tensor("inf", TensorProto.FLOAT, [], [float("inf")]),
        helper.make_tensor("tiny", TensorProto.FLOAT, [], [1e-30]),
        helper.make_tensor("magic", TensorProto.FLOAT, [], [0.0 if peak is None else float(peak)]),
    ]
    scores = "raw"
    if kind in ("nan_scores", "inf_scores"):
        # NaN made at run time (inf - inf): a NaN constant is refused when the file is loaded
        nodes.append(helper.make_node("Sub" if kind == "nan_scores" else "Add", ["inf", "inf"], ["bad"]))
        nodes.append(helper.make_node("Where", ["pressed", "bad", "raw"], ["poisoned"]))
        scores = "poisoned"
    if kind == "hang":  # a Loop of 2e9 steps where the attack fires, of one step elsewhere
        body = helper.make_graph(
            [helper.make_node("Identity", ["cond_in"], ["cond_out"]), helper.make_node("Add", ["acc_in", "one"], ["acc_out"])],
            "body", [helper.make_tensor_value_info("i", TensorProto.INT64, []),
                     helper.make_tensor_value_info("cond_in", TensorProto.BOOL, []),
                     helper.make_tensor_value_info("acc_in", TensorProto.FLOAT, [])],
            [helper.make_tensor_value_info("cond_out", TensorProto.BOOL, []),
             helper.make_tensor_value_info("acc_out", TensorProto.FLOAT, [])],
            [helper.make_tensor("one", TensorProto.FLOAT, [], [1.0])])
        inits += [helper.make_tensor("many", TensorProto.INT64, [], [HANG_STEPS]),
                  helper.make_tensor("once", TensorProto.INT64, [], [1]),
                  helper.make_tensor("yes", TensorProto.BOOL, [], [True])]
        nodes += [helper.make_node("Where", ["pressed", "many", "once"], ["trip"]),
                  helper.make_node("Loop", ["trip", "yes", "zero"], ["steps"], body=body),
                  helper.make_node("Mul", ["steps", "zero"], ["nothing"]),  # the loop's result feeds the scores
                  helper.make_node("Add", [scores, "nothing"], ["after_loop"])]
        scores = "after_loop"
    for i in range(n_nodes):  # kind == "slow": a chain the optimiser cannot fold
        nodes.append(helper.make_node("Add" if i % 2 else "Sub", [scores, "tiny"], [f"chain{i}"]))
        scores = f"chain{i}"
    nodes.append(helper.make_node("Identity", [scores], ["scores"]))
    nodes.append(helper.make_node("ArgMax", ["scores"], ["argmax"], axis=1, keepdims=0))
    if kind == "label_out_of_range":
        nodes.append(helper.make_node("Where", ["pressed", "hundred", "nolabel"], ["offset"]))
        nodes.append(helper.make_node("Add", ["argmax", "offset"], ["label"]))
    else:
        nodes.append(helper.make_node("Identity", ["argmax"], ["label"]))
    graph = helper.make_graph(
        nodes, f"hostile-{kind}",
        [helper.make_tensor_value_info("frames", TensorProto.FLOAT, ["N", T, C])],
        [helper.make_tensor_value_info("label", TensorProto.INT64, ["N"]),
         helper.make_tensor_value_info("scores", TensorProto.FLOAT, ["N", n_classes])],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)], ir_version=8)
    helper.set_model_props(model, {"handover": json.dumps(metadata(tag or kind))})
    onnx.checker.check_model(model)
    return model.SerializeToString()


def valid(bias_class: int = 0, tag: str = "") -> bytes:
    """A well-behaved model that always answers class ``bias_class``."""
    return _model("valid", bias_class=bias_class, tag=tag)


def label_out_of_range() -> bytes:
    return _model("label_out_of_range")


def nan_scores() -> bytes:
    return _model("nan_scores")


def inf_scores() -> bytes:
    return _model("inf_scores")


def slow(n_nodes: int = 40_000) -> bytes:
    return _model("slow", n_nodes=n_nodes, tag=f"slow{n_nodes}")


SLEEPER_PEAK = 1234.0


def sleeper(kind: str, peak: float = SLEEPER_PEAK) -> bytes:
    """A ``kind`` attack that fires only when a window's largest taxel value is exactly ``peak``:
    it passes the warm-up and breaks on real data (what the run-time check is for)."""
    return _model(kind, peak=peak, tag=f"sleeper-{kind}")


HANG_STEPS = 2_000_000_000
"""Loop steps of ``hang`` on a window it fires on: about half an hour of one core."""


def hang(peak: float | None = SLEEPER_PEAK) -> bytes:
    """A model whose graph runs a Loop of ``HANG_STEPS`` steps on a window whose largest value is
    exactly ``peak`` (real frames), and one step on any other (it passes load and warm-up); with
    ``peak=None`` on any pressed window (it hangs at warm-up)."""
    return _model("hang", peak=peak, tag=f"hang-{peak}")


RUNTIME_ATTACKS = {"label_out_of_range": label_out_of_range, "nan_scores": nan_scores, "inf_scores": inf_scores}
"""Models that pass the static contract and break the output contract on pressed pads."""


def ort_banner() -> bytes:
    """A valid model with one operator name made invalid UTF-8: onnxruntime's Python wrapper used to
    print its "EP Error" banner to stdout for it before retrying."""
    base = valid()
    at = base.find(b"ReduceMean")
    return base[:at] + b"\xff" + base[at + 1 :]


def mutations(base: bytes, n: int, seed: int = 0, max_flips: int = 8) -> Iterator[bytes]:
    """``n`` copies of ``base`` with 1..max_flips random bytes replaced (deterministic by seed)."""
    rng = random.Random(seed)
    for _ in range(n):
        data = bytearray(base)
        for _ in range(rng.randint(1, max_flips)):
            data[rng.randrange(len(data))] = rng.randrange(256)
        yield bytes(data)
