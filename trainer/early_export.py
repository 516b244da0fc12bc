"""Early heads into the one model graph: each head reads the last ``p`` rows of ``frames``.

Why one graph with a head per point: the daemon loads, validates, warms up and swaps one file,
and onnxruntime runs only the nodes an output needs, so asking for ``label_at_4`` costs that
head alone (results/latency.md). The daemon passes the ring's newest T frames at every point,
so the window's first ``p`` frames are the input's last ``p`` rows: no copy, no second input.
"""

from __future__ import annotations

import numpy as np

from runtime.early import head_outputs

__all__ = ["add_heads"]


def add_heads(proto, full_model, heads, points, T: int) -> None:
    """Append one head per point to ``proto``'s graph (in place), with outputs ``label_at_p``, ``scores_at_p``."""
    from onnx import TensorProto, helper

    from trainer.onnx_export import _Graph
    from trainer.svm_head import FeatureLayout, svm_nodes

    classes = [str(c) for c in full_model.classes_]
    for model, p in zip(heads, points, strict=True):
        if [str(c) for c in model.classes_] != classes:
            raise ValueError(f"early head at {p} frames has classes {list(model.classes_)}, the model {classes}")
        if not hasattr(model, "onnx_features") or int(model.n_timepoints_) != p:
            raise ValueError(f"early head at {p} frames must be a FeatureSVC fitted on {p} frames")
        g = _Graph(prefix=f"at{p}_")
        window = g.op("Slice", ["frames", g.const("start", [T - p], np.int64), g.const("end", [T], np.int64),
                                g.const("axis", [1], np.int64)], "frames")
        hist = g.name("histogram")
        parts = model.onnx_features(g, window, hist)
        label, scores = head_outputs(p)
        svm_nodes(g, hist, model.svm_, model.scaler_, FeatureLayout(parts.columns, parts.width, parts.scales),
                  label_out=label, scores_out=scores)
        proto.graph.node.extend(g.nodes)
        proto.graph.initializer.extend(g.initializers)
        proto.graph.output.extend([helper.make_tensor_value_info(label, TensorProto.INT64, ["N"]),
                                   helper.make_tensor_value_info(scores, TensorProto.FLOAT, ["N", len(classes)])])
