"""The SVM end of every exported graph: scaler, kernel, one-vs-one decisions, votes, ovr scores, label.

Why this shape: onnxruntime pays per node, and the RBF kernel as squared differences to every
support vector (``[N, M, F]``: Sub, then ReduceSumSquare) was the costliest pair of nodes in the
graph. Here the StandardScaler and gamma fold into one per-feature map
``u = (x - mean) * sqrt(gamma) / scale`` (so ``||u - sqrt(gamma) sv_m||^2 = gamma d_m``), and the
kernel's exponent is one Gemm: ``e_m = 2 u . (sqrt(gamma) sv_m) - ||u||^2 = gamma ||sv_m||^2 - gamma d_m``.
The constant ``exp(-gamma ||sv_m||^2)`` goes into the dual coefficients (when it cannot underflow:
``FOLD_LIMIT``), else into an Add before the Exp. No cancellation is hidden: ``trainer.numerics``
bounds exactly this arithmetic (``rbf_decision_bounds``), and ``handover verify`` checks it.

One Gemm gives the one-vs-one decisions and the summed confidences side by side; a HardSigmoid
makes the wins (``WIN_SLOPE``); the votes and the scores read their own columns through zero rows, and scikit-learn's ovr confidence term
``conf / (3 (|conf| + 1))`` is ``Softsign(conf) / 3`` (the Gemm's ``alpha``). A linear SVM takes the
scaler into its weights and intercepts (``linear_constants``): one Gemm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FOLD_LIMIT", "FeatureLayout", "RbfConstants", "linear_constants", "svm_nodes"]

FOLD_LIMIT = 60.0
"""Largest ``gamma ||sv||^2`` folded into the coefficients: exp(-60) ~ 1e-26 stays a normal float32
coefficient, and the exponent (at most ``gamma ||sv_m||^2``) stays far below float32's exp overflow (88)."""
THIRD = 1.0 / 3.0
WIN_SLOPE = float(np.finfo(np.float32).max)
"""``HardSigmoid(dec) = clip(WIN_SLOPE dec, 0, 1)``: a one-vs-one win as one node (not two: Greater, Cast).
It is 1 for every decision > 0 down to 2.9e-39 and 0 for every decision <= 0, libsvm's rule; only a
subnormal decision (below 1.2e-38) could give part of a vote, and such a decision is within float32
rounding of 0 anyway: a near tie that no float32 graph decides reliably (``trainer.numerics``)."""


@dataclass(frozen=True)
class RbfConstants:
    """The expanded RBF kernel's constants in float64 (the graph stores them as float32)."""

    mean: np.ndarray | None
    """``[F]`` subtracted first (None: no scaler)."""
    unit: np.ndarray
    """``[F]`` ``sqrt(gamma) / scale``: ``u = (x - mean) * unit``."""
    support: np.ndarray
    """``[M, F]`` ``2 sqrt(gamma) sv``: the exponent's Gemm weights (transposed in the graph)."""
    offset: np.ndarray
    """``[M]`` ``-gamma ||sv_m||^2``."""
    folded: bool
    """Whether ``exp(offset)`` is folded into the coefficients (else an Add of ``offset``)."""

    @classmethod
    def of(cls, svm, scaler, layout: FeatureLayout | None = None) -> RbfConstants:
        """From the fitted SVC and scaler; ``layout``: the graph's feature columns (None: in order)."""
        gamma = float(svm._gamma)
        sv = np.asarray(svm.support_vectors_, dtype=np.float64)
        scale = np.ones(sv.shape[1]) if scaler is None else np.asarray(scaler.scale_, dtype=np.float64)
        mean = None if scaler is None else np.asarray(scaler.mean_, dtype=np.float64)
        offset = -gamma * (sv**2).sum(axis=1)
        layout = layout or FeatureLayout(np.arange(sv.shape[1]), sv.shape[1])
        # columns the graph computes but the SVM does not use get zero weight (and no centre); a column
        # holding a feature times s gets its centre times s and its unit over s (u is unchanged)
        return cls(None if mean is None else layout.spread(mean * layout.scale_of_each()),
                   layout.per_unit(np.sqrt(gamma) / scale), layout.spread(2.0 * np.sqrt(gamma) * sv), offset,
                   bool(offset.size == 0 or offset.min() >= -FOLD_LIMIT))


@dataclass(frozen=True)
class FeatureLayout:
    """Where the graph's feature tensor holds each feature: ``columns[i]`` of reference feature i,
    ``width`` columns in all, ``scales[i]`` times the reference's value (None: 1;
    ``trainer.features.base.OnnxParts``)."""

    columns: np.ndarray
    width: int
    scales: np.ndarray | None = None

    def scale_of_each(self) -> np.ndarray:
        from trainer.features.base import scale_of_each

        return scale_of_each(self.columns, self.scales)

    @property
    def scaled(self) -> bool:
        return bool(np.any(self.scale_of_each() != 1.0))

    def per_unit(self, values: np.ndarray) -> np.ndarray:
        """Per-feature factors ``[..., F]`` (weights on the reference's features) laid out for the
        graph's columns: divided by each column's scale, then ``spread``."""
        return self.spread(np.asarray(values, dtype=np.float64) / self.scale_of_each())

    def spread(self, values: np.ndarray, fill: float = 0.0) -> np.ndarray:
        """``values`` ``[..., F]`` (reference order) laid out as ``[..., width]``, ``fill`` elsewhere."""
        values = np.asarray(values, dtype=np.float64)
        out = np.full((*values.shape[:-1], self.width), fill)
        out[..., self.columns] = values
        return out

    @property
    def in_order(self) -> bool:
        from trainer.features.base import columns_in_order

        return columns_in_order(self.columns, self.width)


def head_matrices(svm, scaler=None) -> dict[str, np.ndarray]:
    """The constants of the one-vs-one head (float64): ``pair_coef`` ``[M, P + K]`` (decisions, then
    summed confidences; times ``exp(offset)`` when folded), ``pair_intercept``, ``vote_diff``
    ``[P + K, K]`` (zero rows for the confidences), ``vote_base``, ``conf_pick`` ``[P + K, K]``."""
    from trainer.onnx_export import svm_pair_coefficients, vote_matrices

    coef, intercept, pairs = svm_pair_coefficients(svm)
    n_classes, n_pairs = len(svm.classes_), len(pairs)
    vote_diff, vote_base, conf_sign = vote_matrices(pairs, n_classes)
    both = np.concatenate([coef, coef @ conf_sign], axis=1)
    if svm.kernel == "rbf":
        rbf = RbfConstants.of(svm, scaler)
        if rbf.folded:
            both = both * np.exp(rbf.offset)[:, None]
    return {"pair_coef": both, "pair_intercept": np.concatenate([intercept, intercept @ conf_sign]),
            "vote_diff": np.concatenate([vote_diff, np.zeros((n_classes, n_classes))]), "vote_base": vote_base,
            "conf_pick": np.concatenate([np.zeros((n_pairs, n_classes)), np.eye(n_classes)])}


def linear_constants(svm, scaler=None) -> tuple[np.ndarray, np.ndarray]:
    """A linear SVM's weights ``[F, P + K]`` and intercepts (decisions, then summed confidences) on the
    features before the scaler: ``((x - mean) / scale) W + b = x (W / scale) + (b - (mean / scale) W)``,
    one Gemm (``trainer.numerics`` bounds it on the raw features' magnitudes)."""
    head = head_matrices(svm, scaler)
    weights = np.asarray(svm.support_vectors_, dtype=np.float64).T @ head["pair_coef"]
    intercept = head["pair_intercept"]
    if scaler is not None:
        weights = weights / np.asarray(scaler.scale_, dtype=np.float64)[:, None]
        intercept = intercept - np.asarray(scaler.mean_, dtype=np.float64) @ weights
    return weights, intercept


def svm_nodes(g, features: str, svm, scaler=None, layout: FeatureLayout | None = None, label_out: str = "label",
              scores_out: str = "scores") -> None:
    """Append scaler, kernel, decisions, votes, scikit-learn's ovr scores and the voted label;
    ``layout``: where ``features`` holds each of the SVM's features (None: in order)."""
    head = head_matrices(svm, scaler)
    if svm.kernel == "rbf":
        inputs = _rbf_kernel_nodes(g, features, RbfConstants.of(svm, scaler, layout))
        weights, intercept, hint = head["pair_coef"], head["pair_intercept"], "pair_coef"
    elif svm.kernel == "linear":
        weights, intercept = linear_constants(svm, scaler)
        inputs, hint = features, "pair_weights"
        if layout is not None:
            weights = layout.per_unit(weights.T).T
    else:
        raise ValueError(f"kernel {svm.kernel!r} is not exported (rbf and linear are)")
    dec = g.op("Gemm", [inputs, g.const(hint, weights), g.const("pair_intercept", intercept)], "decision")  # [N, P + K]
    pos = g.op("HardSigmoid", [dec], "wins", alpha=WIN_SLOPE, beta=0.0)  # 1 where dec > 0, else 0
    votes = g.op("Gemm", [pos, g.const("vote_diff", head["vote_diff"]), g.const("vote_base", head["vote_base"])], "votes")
    soft = g.op("Softsign", [dec], "conf_soft")  # conf / (|conf| + 1) on the confidence columns
    g.op("Gemm", [soft, g.const("conf_pick", head["conf_pick"]), votes], outputs=[scores_out], alpha=THIRD)
    g.op("ArgMax", [votes], outputs=[label_out], axis=1, keepdims=0)


def _rbf_kernel_nodes(g, features: str, rbf: RbfConstants) -> str:
    """``exp(e)`` ``[N, M]`` (see the module docstring)."""
    x = features if rbf.mean is None else g.op("Sub", [features, g.const("feature_mean", rbf.mean)], "centred")
    u = g.op("Mul", [x, g.const("rbf_unit", rbf.unit)], "rbf_u")
    norm = g.op("ReduceSumSquare", [u], "rbf_norm", axes=[1], keepdims=1)  # [N, 1]
    exponent = g.op("Gemm", [u, g.const("rbf_support", rbf.support), norm], "rbf_exponent", transB=1, beta=-1.0)
    if not rbf.folded:
        exponent = g.op("Add", [exponent, g.const("rbf_offset", rbf.offset)], "rbf_exponent_offset")
    return g.op("Exp", [exponent], "kernel")
