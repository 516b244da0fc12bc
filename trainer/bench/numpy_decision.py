"""The default model's decision in plain numpy, read from its ONNX graph: a yardstick for latency.

Why: onnxruntime's share of a decision is measured against what the same arithmetic costs
without it, in the same run (a ratio holds on a noisy machine where absolute figures do not).
Parameters come from the graph's initializers (codeword kernel and norms, pad groups, the SVM's
pair weights and vote matrices), so no scikit-learn is needed. Only the default's kind is
implemented: one hard codebook with an explicit derivative, per-pad histograms, a linear SVM and no
scaler. ``NumpyDecision.of(path)`` returns None for any other graph.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from runtime.model import CODEWORD_KERNEL

_SUPPORTED_OPS = frozenset({"Abs", "ReduceMax", "Greater", "Cast", "Unsqueeze", "Conv", "ArgMin", "OneHot", "ReduceSum",
                            "Equal", "Transpose", "Mul", "MatMul", "Max", "Div", "Reshape", "Gemm", "Add", "ArgMax"})


class NumpyDecision:
    """``__call__(window [T, C] float32) -> (label, scores [n_classes])`` in float32 numpy."""

    def __init__(self, params: dict[str, np.ndarray]) -> None:
        kernel = params[CODEWORD_KERNEL]  # [K, 1, W, 1], -2 * codebook
        self.K, self.W = int(kernel.shape[0]), int(kernel.shape[2])
        self.kernel_t = np.ascontiguousarray(kernel[:, 0, :, 0].T)  # [W, K]
        self.sqnorm = params["codeword_sqnorm"].astype(np.float32)
        self.groups = params["group_of_channel"]  # [G, C]
        self.windows_per_channel = params["windows_per_channel"]  # [C, G]
        self.weights = params["pair_weights"]
        self.intercept = params["pair_intercept"]
        self.vote_diff, self.vote_base = params["vote_diff"], params["vote_base"]
        self.conf_sign = params["conf_sign"]
        self.n_channels = int(self.groups.shape[1])
        self._offsets = (np.arange(self.n_channels) * self.K)[None]

    @classmethod
    def of(cls, path: str | Path) -> NumpyDecision | None:
        """From an exported graph of the default's kind, or None (another kind: not implemented here)."""
        import onnx
        from onnx import numpy_helper

        proto = onnx.load(str(path))
        ops = [n.op_type for n in proto.graph.node]
        if set(ops) - _SUPPORTED_OPS or ops.count("Conv") != 2 or ops.count("Gemm") != 2:
            return None
        params = {}
        for init in proto.graph.initializer:
            params.setdefault(init.name.rsplit("_", 1)[0], numpy_helper.to_array(init))
        needed = (CODEWORD_KERNEL, "codeword_sqnorm", "group_of_channel", "windows_per_channel", "pair_weights",
                  "pair_intercept", "vote_diff", "vote_base", "conf_sign")
        if any(k not in params for k in needed):
            return None
        return cls(params)

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
        hist = (counts / n_windows[:, None]).astype(np.float32).ravel()
        dec = hist @ self.weights + self.intercept
        votes = (dec > 0).astype(np.float32) @ self.vote_diff + self.vote_base
        conf = dec @ self.conf_sign
        return int(votes.argmax()), votes + conf / (np.abs(conf) * 3.0 + 3.0)
