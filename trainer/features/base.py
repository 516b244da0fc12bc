"""What every feature family here shares: a scikit-learn transformer on ``(n_cases, n_channels,
n_timepoints)`` that also writes its own ONNX nodes and bounds its float32 error.

A family implements ``_fit(X, y)``, ``_transform(X)`` (the float64 reference), ``error_bounds(X)``
(``(n, F)`` bound on |float32 graph - float64 reference|, for ``handover verify``) and its ONNX
nodes: ``onnx_nodes(g, frames)`` (``frames`` ``[N, T, C]`` -> ``[N, F]`` in the reference's order),
or ``onnx_parts(g, frames)``: tensors ``[N, k_i]`` in whatever layout the nodes make cheaply, and
where each reference feature sits in their concatenation. ``FeatureSVC`` joins the parts of all
families with one Concat and lays the scaler and support vectors out to match, so no node is spent
on putting features in order (onnxruntime pays per node).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.utils.validation import check_is_fitted

from trainer.bow import as_cases, check_case_shape
from trainer.features.signals import pad_shapes_for

__all__ = [
    "FeatureFamily", "OnnxParts", "columns_in_order", "join_parts", "pad_bounds", "scale_of_each"
]


def scale_of_each(columns: np.ndarray, scales: np.ndarray | None) -> np.ndarray:
    """Each feature column's scale, None (all 1) spelled out as ones (``OnnxParts``, ``FeatureLayout``)."""
    return np.ones(len(columns)) if scales is None else np.asarray(scales, dtype=np.float64)


@dataclass(frozen=True)
class OnnxParts:
    """A family's ONNX tensors ``[N, k_i]``; ``columns[i]``: where reference feature i sits in their
    concatenation, ``width`` columns wide (columns not listed are computed and ignored); ``scales[i]``
    (None: all 1): the column holds reference feature i times it, so a constant factor is left to the
    SVM's weights instead of costing a node."""

    tensors: list[str]
    columns: np.ndarray
    width: int
    scales: np.ndarray | None = None
    widths: tuple[int, ...] | None = None
    """Columns of each tensor (None: unknown). With them, a tensor two families share (the same
    name) is joined into the features once."""

    def scale_of_each(self) -> np.ndarray:
        return scale_of_each(self.columns, self.scales)

    @classmethod
    def in_order(cls, tensors: list[str], n_features: int) -> OnnxParts:
        """Parts that already hold the features in the reference's order."""
        return cls(tensors, np.arange(int(n_features)), int(n_features))


def join_parts(every: Sequence[OnnxParts]) -> OnnxParts:
    """The parts of several families as one: their tensors in order (to be joined by one Concat) and
    where each family's features sit. A tensor two families share (same name, ``widths`` known) is
    joined once and read where it is, unless the same columns of it are already taken there."""
    tensors: list[str] = []
    columns, scales, width = [], [], 0
    start_of: dict[str, int] = {}
    for parts in every:
        scales.append(parts.scale_of_each())
        if parts.widths is None:  # one block of columns
            tensors += parts.tensors
            columns.append(parts.columns + width)
            width += parts.width
            continue
        used = set(np.concatenate(columns).tolist()) if columns else set()
        local = np.concatenate([[0], np.cumsum(parts.widths)]).astype(np.int64)
        which = np.searchsorted(local, parts.columns, side="right") - 1
        starts = []
        for i, (tensor, size) in enumerate(zip(parts.tensors, parts.widths, strict=True)):
            start = start_of.get(tensor)
            if start is None or used & set((start + parts.columns[which == i] - local[i]).tolist()):
                start, width = width, width + size
                tensors.append(tensor)
                start_of.setdefault(tensor, start)
            starts.append(start)
        columns.append(np.asarray(starts, dtype=np.int64)[which] + parts.columns - local[which])
    return OnnxParts(tensors, np.concatenate(columns).astype(np.int64), width, np.concatenate(scales))


def columns_in_order(columns: np.ndarray, width: int) -> bool:
    """Whether ``width`` columns hold exactly the reference's features, in order (no layout to undo)."""
    return width == len(columns) and bool(np.array_equal(columns, np.arange(width)))


class FeatureFamily(TransformerMixin, BaseEstimator):
    """Base of the feature families: input checks, pad layout, fitted shape."""

    learns_from_cases = False
    """Whether ``fit`` learns from the training cases (not just their layout): when not, a case's features
    depend on that case alone and serve any fit that contains it (``FeatureSVC.case_features``)."""

    def _layout(self, n_channels: int) -> list[tuple[int, int]]:
        sizes = self.pad_sizes if self.pad_sizes is not None else (n_channels,)
        if any(not float(s).is_integer() or int(s) <= 0 for s in sizes):
            raise ValueError(f"pad_sizes {tuple(sizes)}: give the number of taxels of each pad, all positive "
                             "(e.g. [78, 78, 78] for the three distal pads)")
        if sum(int(s) for s in sizes) != n_channels:
            raise ValueError(f"pad_sizes {tuple(sizes)} must sum to n_channels={n_channels}")
        return pad_shapes_for(sizes, getattr(self, "pad_shapes", None))

    def fit(self, X, y=None):
        X = as_cases(X)
        self.shapes_ = self._layout(X.shape[1])
        self.n_channels_, self.n_timepoints_ = X.shape[1], X.shape[2]
        self.n_features_in_ = X.shape[1] * X.shape[2]
        self._fit(X, y)
        return self

    def _fit(self, X: np.ndarray, y) -> None:
        """Learn what the family needs beyond the layout (nothing by default)."""

    def _check(self, X) -> np.ndarray:
        check_is_fitted(self, "shapes_")
        return check_case_shape(self, X)

    def transform(self, X) -> np.ndarray:
        return self._transform(self._check(X))

    def onnx_parts(self, g, frames: str) -> OnnxParts:
        """The family's ONNX tensors and where each feature sits in them (default: ``onnx_nodes``)."""
        return OnnxParts.in_order([self.onnx_nodes(g, frames)], self.n_features_out_)

    def onnx_nodes(self, g, frames: str) -> str:
        """``[N, F]`` in the reference's order: the parts joined and, where needed, reordered (a Gather)."""
        parts = self.onnx_parts(g, frames)
        joined = g.op("Concat", parts.tensors, "family_features", axis=1) if len(parts.tensors) > 1 else parts.tensors[0]
        if not columns_in_order(parts.columns, parts.width):
            joined = g.op("Gather", [joined, g.const("feature_order", parts.columns, np.int64)], "family_ordered", axis=1)
        scales = parts.scale_of_each()
        if np.all(scales == 1.0):
            return joined
        return g.op("Mul", [joined, g.const("feature_unscale", 1.0 / scales)], "family_unscaled")

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.input_tags.three_d_array = True
        return tags


def pad_bounds(shapes: Sequence[tuple[int, int]]) -> list[tuple[int, int]]:
    """``(start, stop)`` channel range of each pad."""
    out, start = [], 0
    for rows, cols in shapes:
        out.append((start, start + rows * cols))
        start += rows * cols
    return out
