"""The BoW model's decision in plain numpy, read from its ONNX graph: a yardstick for latency.

Only one kind is implemented: one hard codebook with an explicit derivative, per-pad histograms,
a linear SVM and no scaler (the BoW default before the feature default). ``NumpyBow.of(parts)``
returns None for any other graph.
"""

from __future__ import annotations

import numpy as np

from runtime.model import CODEWORD_KERNEL
from trainer.bench.numpy_graph import GraphParts, SvmHead

_SUPPORTED_OPS = frozenset({"Abs", "ReduceMax", "Greater", "Cast", "HardSigmoid", "Unsqueeze", "Conv", "ArgMin", "OneHot", "ReduceSum",
                            "Equal", "Transpose", "Mul", "MatMul", "Max", "Div", "Reshape", "Gemm", "Add", "ArgMax",
                            "Softsign"})
_NEEDED = (CODEWORD_KERNEL, "codeword_sqnorm", "group_of_channel", "windows_per_channel", "pair_weights")


class NumpyBow:
    """``__call__(window [T, C] float32) -> (label, scores [n_classes])`` in float32 numpy."""

    def __init__(self, parts: GraphParts) -> None:
        kernel = parts.first(CODEWORD_KERNEL)  # [K, 1, W, 1], -2 * codebook
        self.K, self.W = int(kernel.shape[0]), int(kernel.shape[2])
        self.kernel_t = np.ascontiguousarray(kernel[:, 0, :, 0].T)  # [W, K]
        self.sqnorm = parts.first("codeword_sqnorm").astype(np.float32)
        self.groups = parts.first("group_of_channel")  # [G, C]
        self.windows_per_channel = parts.first("windows_per_channel")  # [C, G]
        self.head = SvmHead(parts)
        self.n_channels = int(self.groups.shape[1])
        self._offsets = (np.arange(self.n_channels) * self.K)[None]

    @classmethod
    def of(cls, parts: GraphParts) -> NumpyBow | None:
        """From a graph of this kind, or None (another kind: not implemented here)."""
        ops = parts.ops
        if set(ops) - _SUPPORTED_OPS or ops.count("Conv") != 2 or ops.count("Gemm") != 3:
            return None
        if not parts.has(*_NEEDED) or not SvmHead.readable(parts):
            return None
        return cls(parts)

    def __call__(self, window: np.ndarray) -> tuple[int, np.ndarray]:
        x = window.reshape(-1, self.n_channels)
        active = (np.abs(x).max(axis=0) > 0).astype(np.float32)  # [C]
        deriv = x[1:] - x[:-1]  # [T-1, C]
        windows = np.lib.stride_tricks.sliding_window_view(deriv, self.W, axis=0)  # [S, C, W]
        scores = windows @ self.kernel_t + self.sqnorm  # [S, C, K]
        words = scores.argmin(axis=2)  # [S, C], first index on ties like ArgMin
        per_channel = np.bincount((words + self._offsets).ravel(), minlength=self.n_channels * self.K)
        counts = self.groups @ (per_channel.reshape(self.n_channels, self.K) * active[:, None])  # [G, K]
        n_windows = np.maximum(active @ self.windows_per_channel, 1.0)  # [G]
        return self.head((counts / n_windows[:, None]).astype(np.float32).ravel())
