"""All pads of a window as one ``[N, G, S, T]`` tensor, so a feature is a handful of ONNX nodes for
every pad instead of a chain per pad (onnxruntime pays per node, and a per-pad chain multiplies it).

Pads differ in size (SDH-2: 84 taxels proximal, 78 distal): each pad is padded to the largest
size ``S`` by repeating one of its own taxels (so a maximum is unchanged), with a 0/1 mask for
sums and an offset for order statistics: the padding slots get ``+inf`` and ``-inf`` in equal
numbers, so the median of the padded values is the pad's median (exact, no arithmetic on real
values: adding 0 leaves them bit for bit).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["PadBatch", "magnitude_nodes", "median_nodes", "peak_nodes"]


@dataclass(frozen=True)
class PadBatch:
    """Layout of the padded pads: taxel index ``[G, S]``, mask ``[G, S]``, median offset ``[G, S]``."""

    index: np.ndarray
    mask: np.ndarray
    offset: np.ndarray
    sizes: np.ndarray

    @classmethod
    def of(cls, shapes: Sequence[tuple[int, int]]) -> PadBatch:
        sizes = np.array([r * c for r, c in shapes])
        width = int(sizes.max())
        index = np.zeros((len(sizes), width), dtype=np.int64)
        mask = np.zeros((len(sizes), width))
        offset = np.zeros((len(sizes), width))
        start = 0
        for g, size in enumerate(sizes):
            index[g] = start  # padding slots repeat the pad's first taxel
            index[g, :size] = np.arange(start, start + size)
            mask[g, :size] = 1.0
            extra = width - size
            offset[g, size : size + extra // 2] = np.inf
            offset[g, size + extra // 2 :] = -np.inf
            start += size
        return cls(index, mask, offset, sizes)

    @property
    def padded(self) -> bool:
        return bool((self.mask == 0).any())

    @property
    def median_in_one(self) -> bool:
        """Whether one TopK over the padded rows gives every pad's median: each pad's missing slots
        must split evenly into ``+inf`` and ``-inf`` ones (true for SDH-2 pads, 84 and 78 taxels)."""
        return bool(((self.sizes.max() - self.sizes) % 2 == 0).all())

    def nodes(self, g, frames: str) -> str:
        """``frames`` ``[N, T, C]`` -> ``[N, G, S, T]`` (one Transpose, then a Gather of whole time series,
        or a Reshape where no pad is padded), built once per graph."""
        def build() -> str:
            series = g.op("Transpose", [frames], "series", perm=[0, 2, 1])  # [N, C, T]
            if not self.padded:  # pads of one size in channel order: a view, no copy
                shape = [0, *self.index.shape, -1]
                return g.op("Reshape", [series, g.const("pad_shape", shape, np.int64)], "pad_batch")
            return g.op("Gather", [series, g.const("pad_slots", self.index, np.int64)], "pad_batch", axis=1)

        return g.shared(("pad_batch", frames, self.index.tobytes()), build)


def peak_nodes(g, padded: str) -> str:
    """Each pad's largest value ``[N, G]`` (padding repeats a taxel of the pad), built once per graph."""
    return g.shared(("pad_peak", padded), lambda: g.op("ReduceMax", [padded], "pad_peak", axes=[2, 3], keepdims=0))


def magnitude_nodes(g, padded: str) -> str:
    """``|padded|``, built once per graph (the level statistics and the median's shortcut read it)."""
    return g.shared(("pad_magnitude", padded), lambda: g.op("Abs", [padded], "magnitude"))


def median_nodes(g, batch: PadBatch, padded: str, peak: str, n_t: int) -> str:
    """Median of each pad's values ``[N, G]`` from ``padded`` ``[N, G, S, T]`` (``peak``: ``[N, G]``).

    Exact both ways, cheap where it can be: when in every pad of every window fewer than half the
    values can be non-zero (at most ``(size * T - 1) // 2`` from the taxels not zero all window
    long), the middle values are 0 and an If returns 0 without sorting. That holds for 95-100 %
    of the windows of the real SDH-2 recordings (contact covers less than half a pad). Otherwise
    TopK of the largest half (unordered), then its smallest one or two."""
    width = int(batch.sizes.max())
    if not batch.median_in_one:
        parts = []
        for p, size in enumerate(batch.sizes):
            pad = g.op("Slice", [padded, g.const("start", [p, 0], np.int64), g.const("stop", [p + 1, size], np.int64),
                                 g.const("axes", [1, 2], np.int64)], "one_pad")
            parts.append(_middle_nodes(g, pad, int(size) * n_t, 1))
        return g.op("Concat", parts, "median", axis=1)
    # Sign of a sum of magnitudes is 1 for a taxel touched in the window, else 0 (one node for Greater
    # and Cast); the sum over time as a MatMul on the magnitudes the level statistics read anyway
    # (measured faster than a ReduceL1 of the frames)
    l1 = g.op("MatMul", [magnitude_nodes(g, padded), g.const("time_ones", np.ones((n_t, 1)))], "taxel_l1")
    touched = g.op("Sign", [l1], "touched_f")  # [N, G, S, 1]
    # each pad's touched taxels, each weighing 1 / (most + 1/2): the pads may take the shortcut when
    # every weighted count is at most 1 (counts are small integers: float32 rounding cannot cross 1,
    # the nearest counts are 1 / (2 most + 1) away from it); padding slots weigh 0
    most = ((batch.sizes * n_t - 1) // 2) // n_t  # touched taxels whose T values stay below half the pad's
    weights = (batch.mask / (most[:, None] + 0.5))[:, None, :]  # [G, 1, S]
    count = g.op("MatMul", [g.const("touch_weights", weights), touched], "touch_count")  # [N, G, 1, 1]
    worst = g.op("ReduceMax", [count], "worst", keepdims=0)
    zero_median = g.op("LessOrEqual", [worst, g.const("one", 1.0)], "zero_median")
    then_g, else_g = type(g)(prefix=g.name("then") + "_"), type(g)(prefix=g.name("else") + "_")
    then_out = then_g.op("Mul", [peak, then_g.const("zero", 0.0)], "median")  # [N, G] zeros
    values = padded
    if batch.padded:
        values = else_g.op("Add", [padded, else_g.const("median_offset", batch.offset[:, :, None])], "median_values")
    else_out = _middle_nodes(else_g, values, width * n_t, len(batch.sizes))
    return g.op("If", [zero_median], "median", then_branch=_subgraph(then_g, then_out),
                else_branch=_subgraph(else_g, else_out))


def _subgraph(sub, output: str):
    from onnx import TensorProto, helper

    return helper.make_graph(sub.nodes, sub.prefix + "branch", [],
                             [helper.make_tensor_value_info(output, TensorProto.FLOAT, None)], sub.initializers)


def _middle_nodes(g, values: str, total: int, n_rows: int) -> str:
    """``values`` ``[N, n_rows, ...]`` holding ``total`` values per row -> the rows' medians ``[N, n_rows]``:
    TopK of the largest half (unordered), then its smallest one or two."""
    rows = g.op("Reshape", [values, g.const("rows", [0, n_rows, total], np.int64)], "median_rows")
    k = total // 2 + 1
    top = g.name("top")
    g.op("TopK", [rows, g.const("k", [k], np.int64)], outputs=[top, g.name("top_idx")], axis=2, largest=1, sorted=0)
    n_mid = 2 if total % 2 == 0 else 1
    middle = g.name("middle")
    g.op("TopK", [top, g.const("k_mid", [n_mid], np.int64)], outputs=[middle, g.name("middle_idx")], axis=2,
         largest=0, sorted=1)
    return g.op("ReduceMean", [middle], "median", axes=[2], keepdims=0)
