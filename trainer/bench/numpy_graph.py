"""What the numpy-only yardsticks read from an exported graph, and the SVM head they share.

Why: the latency benchmark times the graph against the same arithmetic in plain numpy. Every
parameter comes from the graph file itself (its initializers and its ``handover`` metadata), so
the exporter stays the one owner of the format and no scikit-learn is needed at run time.
Initializers are found by the hint the exporter gave them (``trainer.onnx_export._Graph.const``
names them ``<hint>_<n>``), in graph order, then those of the If branches.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class GraphParts:
    """An exported graph as the yardsticks read it: node op types, initializers by hint, metadata."""

    ops: tuple[str, ...]
    params: dict[str, list[np.ndarray]]
    meta: dict

    @classmethod
    def load(cls, path: str | Path) -> GraphParts:
        import onnx
        from onnx import numpy_helper

        proto = onnx.load(str(path))
        params: dict[str, list[np.ndarray]] = {}
        # an If branch's names carry its prefix, which is its graph's name without "branch"
        branches = [(a.g.name.removesuffix("branch"), a.g) for n in proto.graph.node for a in n.attribute
                    if a.type == onnx.AttributeProto.GRAPH]
        for prefix, graph in [("", proto.graph), *branches]:
            for init in graph.initializer:
                hint = init.name.removeprefix(prefix).rsplit("_", 1)[0]
                params.setdefault(hint, []).append(numpy_helper.to_array(init))
        props = {p.key: p.value for p in proto.metadata_props}
        return cls(tuple(n.op_type for n in proto.graph.node), params, json.loads(props.get("handover", "{}")))

    def first(self, hint: str) -> np.ndarray:
        return self.params[hint][0]

    def has(self, *hints: str) -> bool:
        return all(h in self.params for h in hints)


SVM_HEAD = ("pair_intercept", "vote_diff", "vote_base", "conf_pick")
"""Initializers of the one-vs-one head every exported SVM ends with (``trainer.svm_head.svm_nodes``)."""


class SvmHead:
    """``(features [F] float32) -> (label, scores [n_classes])``: as ``trainer.svm_head`` builds it: the
    RBF kernel or the linear weights with the scaler folded in, decisions and summed
    confidences from one product, votes and scikit-learn's ovr scores."""

    def __init__(self, parts: GraphParts) -> None:
        p = parts.first
        self.mean = p("feature_mean") if parts.has("feature_mean") else None
        self.rbf = parts.has("rbf_support")
        if self.rbf:
            self.unit = p("rbf_unit")
            self.support_t = np.ascontiguousarray(p("rbf_support").T)  # [F, M]
            self.offset = p("rbf_offset") if parts.has("rbf_offset") else None
            self.coef = p("pair_coef")
        else:  # the scaler is folded into the weights
            self.coef = p("pair_weights")
        self.intercept, self.vote_diff, self.vote_base, self.conf_pick = (p(k) for k in SVM_HEAD)

    @staticmethod
    def readable(parts: GraphParts) -> bool:
        return parts.has(*SVM_HEAD) and (parts.has("rbf_support", "rbf_unit", "pair_coef") or parts.has("pair_weights"))

    def __call__(self, features: np.ndarray) -> tuple[int, np.ndarray]:
        x = features if self.mean is None else features - self.mean
        if self.rbf:
            u = x * self.unit
            exponent = u @ self.support_t - np.dot(u, u)
            if self.offset is not None:
                exponent = exponent + self.offset
            dec = np.exp(exponent) @ self.coef + self.intercept
        else:
            dec = x @ self.coef + self.intercept
        votes = (dec > 0).astype(np.float32) @ self.vote_diff + self.vote_base
        soft = dec / (np.abs(dec) + np.float32(1.0))
        return int(votes.argmax()), (soft @ self.conf_pick) * np.float32(1.0 / 3.0) + votes
