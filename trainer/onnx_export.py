"""Export a fitted BowSVC (or FlatSVC) as ONE ONNX graph: raw frames ``[N, T, C]`` -> ``label``, ``scores``.

Graph (standard ``ai.onnx`` domain only, opset 17, IR 8), the float64 reference being ``trainer.bow``:

1. active series: ``ReduceMax(|X|, time) > 0`` -> mask ``[N, C]``;
2. derivative: a ``[-1, +1]`` convolution along time (exact for 12-bit integers), or, with
   ``fold_derivative=True``, folded into the codeword kernel;
3. one 2-D convolution with kernel ``-2 * codebook`` and bias ``||c_k||^2`` gives
   ``f_k = ||c_k||^2 - 2 w.c_k`` for every window and codeword at once (``||w||^2`` does not change the argmin);
4. ``ArgMin`` over codewords (first index on ties, like the reference), one ``Equal`` per word, sums over
   windows and pad groups (one MatMul), divided by the active windows (at least 1: no NaN); soft assignment
   and level features join through one Concat into ``histogram``;
5. the SVM (``trainer.svm_head``), the scaler folded in; ``label`` = first class with the most votes.

This replaces skl2onnx's ``SVMClassifier`` and its long node chain. The derivative is explicit by
default: folded, the dot products run on raw values up to 4095 and float32 error grows with them
(``trainer.numerics``).
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from runtime.model import CODEWORD_KERNEL

__all__ = [
    "FEATURE_COLUMNS", "FEATURE_SCALES", "HISTOGRAM", "IR_VERSION", "OPSET", "build_graph", "export_onnx",
    "feature_columns", "feature_scales", "features_nodes", "folded_codebook", "model_metadata", "model_shape",
    "svm_pair_coefficients", "vote_matrices"
]

OPSET = 17
IR_VERSION = 8
HISTOGRAM = "histogram"
"""Name of the BoW histogram tensor inside the graph (``handover verify`` exposes it)."""
FEATURE_COLUMNS = "handover_feature_columns"
"""Model property (JSON list) written when a graph's ``histogram`` holds the features in its own
layout (``trainer.svm_head.FeatureLayout``): the column of each reference feature."""
FEATURE_SCALES = "handover_feature_scales"
"""Model property (JSON list, one per reference feature) written when a graph's ``histogram`` holds
features times a constant (``trainer.svm_head.FeatureLayout.scales``): divide to get the reference's."""
SCORE_MEANING = "sklearn ovr scores: one-vs-one votes + summed confidence / (3 * (|summed confidence| + 1))"


# -- parameters taken from the fitted estimators ------------------------------------------------
def svm_pair_coefficients(svm) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int]]]:
    """Per one-vs-one pair coefficients of every support vector, float64 ``[M, P]``, intercepts ``[P]``
    and the pairs (i, j). Decision ``> 0`` votes for class i (libsvm's sign, also for two classes)."""
    dual = np.asarray(getattr(svm, "_dual_coef_", svm.dual_coef_), dtype=np.float64)
    intercept = np.asarray(getattr(svm, "_intercept_", svm.intercept_), dtype=np.float64)
    n_support = np.asarray(svm.n_support_, dtype=np.int64)
    n_classes = len(n_support)
    starts = np.concatenate([[0], np.cumsum(n_support)])
    pairs = [(i, j) for i in range(n_classes) for j in range(i + 1, n_classes)]
    coef = np.zeros((int(starts[-1]), len(pairs)), dtype=np.float64)
    for p, (i, j) in enumerate(pairs):
        si, sj = slice(starts[i], starts[i + 1]), slice(starts[j], starts[j + 1])
        coef[si, p] = dual[j - 1, si]
        coef[sj, p] = dual[i, sj]
    return coef, intercept.copy(), pairs


def vote_matrices(pairs: list[tuple[int, int]], n_classes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``votes = pos @ vote_diff + vote_base`` (pos = decision > 0) and ``conf = dec @ conf_sign``."""
    win_i = np.zeros((len(pairs), n_classes))
    win_j = np.zeros((len(pairs), n_classes))
    conf = np.zeros((len(pairs), n_classes))
    for p, (i, j) in enumerate(pairs):
        win_i[p, i] = win_j[p, j] = 1.0
        conf[p, i], conf[p, j] = 1.0, -1.0
    return win_i - win_j, win_j.sum(axis=0), conf


# -- graph construction -------------------------------------------------------------------------
class _Graph:
    """Collects nodes and initializers with unique names."""

    def __init__(self, prefix: str = ""):
        self.nodes: list = []
        self.initializers: list = []
        self.prefix = prefix
        self._n = 0
        self._shared: dict = {}

    def shared(self, key, build) -> str:
        """The tensor ``build()`` makes, built once per ``key`` in this graph: feature families that
        need the same intermediate (all pads as one tensor, their peaks) share its nodes."""
        if key not in self._shared:
            self._shared[key] = build()
        return self._shared[key]

    def name(self, hint: str) -> str:
        self._n += 1
        return f"{self.prefix}{hint}_{self._n}"

    def const(self, hint: str, value, dtype=np.float32) -> str:
        from onnx import numpy_helper

        name = self.name(hint)
        self.initializers.append(numpy_helper.from_array(np.asarray(value, dtype=dtype), name))
        return name

    def op(self, op_type: str, inputs: list[str], hint: str | None = None, outputs: list[str] | None = None, **attrs) -> str:
        from onnx import helper

        outs = outputs or [self.name(hint or op_type.lower())]
        self.nodes.append(helper.make_node(op_type, inputs, outs, name=self.name(op_type), **attrs))
        return outs[0]


def _group_matrix(pad_sizes: tuple[int, ...]) -> np.ndarray:
    """``[G, C]`` indicator: 1 where channel c belongs to pad group g."""
    groups = np.zeros((len(pad_sizes), int(sum(pad_sizes))))
    start = 0
    for gi, size in enumerate(pad_sizes):
        groups[gi, start : start + size] = 1.0
        start += size
    return groups


def folded_codebook(codebook: np.ndarray) -> np.ndarray:
    """``[K, W+1]`` weights on raw values that equal the codewords' dot product with the derivative:
    sum_j (x[s+j+1] - x[s+j]) c[j] = sum_i x[s+i] (c[i-1] - c[i]), with c[-1] = c[W] = 0."""
    codebook = np.asarray(codebook, dtype=np.float64)
    padded = np.zeros((codebook.shape[0], codebook.shape[1] + 2))
    padded[:, 1:-1] = codebook
    return padded[:, :-1] - padded[:, 1:]


def _active_nodes(g: _Graph, frames: str) -> str:
    """``[N, C]`` float mask of the series that are not all zero."""
    peak = g.op("ReduceMax", [g.op("Abs", [frames])], "peak", axes=[1], keepdims=0)
    return g.op("Cast", [g.op("Greater", [peak, g.const("zero", 0.0)])], "active", to=1)


def _scale_nodes(g: _Graph, x4: str, deriv: str | None, active: str, codebook: np.ndarray, pad_sizes: tuple[int, ...],
                 n_timepoints: int, soft_tau: float | None = None) -> str:
    """One scale: word weights of every window, summed per series, grouped and normalised ``[N, G*K]``.

    ``deriv`` is the explicit derivative ``[N, 1, T-1, C]``; None folds it into the kernel (raw ``x4``).
    """
    codebook = np.asarray(codebook, dtype=np.float64)
    n_words, window = codebook.shape
    n_windows = n_timepoints - window
    n_groups = len(pad_sizes)
    bias = (codebook**2).sum(axis=1)
    if deriv is None:
        kernel, signal = -2.0 * folded_codebook(codebook), x4
    else:
        kernel, signal = -2.0 * codebook, deriv
    weights = g.const(CODEWORD_KERNEL, kernel.reshape(n_words, 1, -1, 1))
    scores = g.op("Conv", [signal, weights, g.const("codeword_sqnorm", bias)], "word_scores")  # [N, K, S, C]
    if soft_tau is None:
        words = g.op("ArgMin", [scores], "words", axis=1, keepdims=0)  # [N, S, C]
        # word k's count per channel: (words == k) as K planes of S x C, summed over S. Comparing whole
        # planes with one scalar each is what onnxruntime does fast (OneHot's innermost K costs 3x more)
        planes = g.op("Unsqueeze", [words, g.const("axis1", [1], np.int64)], "words4")  # [N, 1, S, C]
        hits = g.op("Equal", [planes, g.const("word_index", np.arange(n_words).reshape(n_words, 1, 1), np.int64)])
        hit_counts = g.op("ReduceSum", [g.op("Cast", [hits], "hits", to=1), g.const("axis2", [2], np.int64)],
                          "word_counts", keepdims=0)  # [N, K, C]
        per_channel = g.op("Transpose", [hit_counts], "per_channel", perm=[0, 2, 1])  # [N, C, K]
    else:
        # softmax(-(f - min f) / tau): every exponent <= 0, so exp never overflows; f differs from
        # the squared distance by ||w||^2, which the softmax does not see
        lowest = g.op("ReduceMin", [scores], "lowest", axes=[1], keepdims=1)
        shifted = g.op("Mul", [g.op("Sub", [scores, lowest], "shifted"), g.const("neg_inv_tau", -1.0 / soft_tau)], "z")
        soft = g.op("Softmax", [shifted], "soft", axis=1)  # [N, K, S, C]
        summed = g.op("ReduceSum", [soft, g.const("axis2", [2], np.int64)], "soft_sum", keepdims=0)  # [N, K, C]
        per_channel = g.op("Transpose", [summed], "per_channel", perm=[0, 2, 1])  # [N, C, K]
    active3 = g.op("Unsqueeze", [active, g.const("axis2", [2], np.int64)], "active3")
    masked = g.op("Mul", [per_channel, active3], "masked")
    groups = _group_matrix(pad_sizes)
    counts = g.op("MatMul", [g.const("group_of_channel", groups), masked], "counts")  # [N, G, K]
    n_active = g.op("MatMul", [active, g.const("windows_per_channel", groups.T * n_windows)], "n_windows")  # [N, G]
    denom = g.op("Max", [n_active, g.const("one", 1.0)], "denom")
    denom3 = g.op("Unsqueeze", [denom, g.const("axis2", [2], np.int64)], "denom3")
    hist = g.op("Div", [counts, denom3], "hist3")
    return g.op("Reshape", [hist, g.const("hist_shape", [0, n_groups * n_words], np.int64)], "scale_hist")


def _level_nodes(g: _Graph, frames: str, level_groups: tuple[int, ...], fullscale: float, n_timepoints: int) -> str:
    """Per pad mean level and mean slope over the window, / fullscale: ``[N, 2G]`` (levels, then slopes)."""
    groups = _group_matrix(level_groups)
    sizes = groups.sum(axis=1)
    mean_t = g.op("ReduceMean", [frames], "mean_over_time", axes=[1], keepdims=0)  # [N, C]
    levels = g.op("MatMul", [mean_t, g.const("level_weights", groups.T / (sizes * fullscale))], "levels")
    last = g.op("Gather", [frames, g.const("last", n_timepoints - 1, np.int64)], "last_frame", axis=1)
    first = g.op("Gather", [frames, g.const("first", 0, np.int64)], "first_frame", axis=1)
    rise = g.op("Sub", [last, first], "rise")
    slope_w = groups.T / (sizes * (n_timepoints - 1) * fullscale)
    slopes = g.op("MatMul", [rise, g.const("slope_weights", slope_w)], "slopes")
    return g.op("Concat", [levels, slopes], "level_features", axis=1)


def _derivative_nodes(g: _Graph, x4: str) -> str:
    deriv_kernel = np.array([-1.0, 1.0]).reshape(1, 1, 2, 1)
    return g.op("Conv", [x4, g.const("deriv_kernel", deriv_kernel)], "deriv")  # [N, 1, T-1, C]


def features_nodes(g: _Graph, frames: str, bow, fold_derivative: bool = False, output: str | None = None) -> str:
    """Append every feature of a fitted BagOfWords (all scales, hard or soft, level features) of
    ``frames`` [N, T, C] in the reference's order; return the ``histogram`` name ``[N, F]`` (or
    ``output`` when the histogram is one part of a larger feature vector)."""
    n_timepoints = int(bow.n_timepoints_)
    pad_sizes = tuple(bow.pad_sizes_)
    active = _active_nodes(g, frames)
    x4 = g.op("Unsqueeze", [frames, g.const("axis1", [1], np.int64)], "x4")  # [N, 1, T, C]
    deriv = None if fold_derivative else _derivative_nodes(g, x4)
    soft = getattr(bow, "assignment", "hard") == "soft"
    parts = [
        _scale_nodes(g, x4, deriv, active, codebook, pad_sizes, n_timepoints, soft_tau=tau if soft else None)
        for _, codebook, tau in bow.scales()
    ]
    if getattr(bow, "level_features", False):
        parts.append(_level_nodes(g, frames, tuple(bow.level_groups_), float(bow.fullscale), n_timepoints))
    joined = g.op("Concat", parts, "features", axis=1) if len(parts) > 1 else parts[0]
    shape = g.const("hist_shape", [0, int(bow.n_features_out_)], np.int64)
    return g.op("Reshape", [joined, shape], outputs=[output or g.prefix + HISTOGRAM])


def model_shape(model) -> tuple[int, int]:
    """(T, C) of a fitted BowSVC, FlatSVC or FeatureSVC."""
    inner = model if hasattr(model, "n_timepoints_") else model.bow_
    return int(inner.n_timepoints_), int(inner.n_channels_)


def build_graph(model, fold_derivative: bool = False):
    """The ONNX ModelProto of a fitted BowSVC or FlatSVC (no metadata yet)."""
    from onnx import TensorProto, helper

    from trainer.svm_head import FeatureLayout, svm_nodes

    n_timepoints, n_channels = model_shape(model)
    g = _Graph()
    layout = None
    if hasattr(model, "onnx_features"):  # FeatureSVC: any mix of feature families
        if fold_derivative:
            raise ValueError("fold_derivative applies to BowSVC graphs only")
        parts = model.onnx_features(g, "frames", HISTOGRAM)
        hist, layout = HISTOGRAM, FeatureLayout(parts.columns, parts.width, parts.scales)
        name = "handover_feature_svm"
    elif hasattr(model, "bow_"):
        hist = features_nodes(g, "frames", model.bow_, fold_derivative)
        name = "handover_bow_svm"
    else:  # flattened-series SVM: channel-major flattening, like X.reshape(n, C * T)
        series = g.op("Transpose", ["frames"], "series", perm=[0, 2, 1])  # [N, C, T]
        shape = g.const("hist_shape", [0, n_channels * n_timepoints], np.int64)
        hist = g.op("Reshape", [series, shape], outputs=[HISTOGRAM])
        name = "handover_flat_svm"
    svm_nodes(g, hist, model.svm_, getattr(model, "scaler_", None), layout)
    graph = helper.make_graph(
        g.nodes,
        name,
        [helper.make_tensor_value_info("frames", TensorProto.FLOAT, ["N", n_timepoints, n_channels])],
        [
            helper.make_tensor_value_info("label", TensorProto.INT64, ["N"]),
            helper.make_tensor_value_info("scores", TensorProto.FLOAT, ["N", len(model.classes_)]),
        ],
        g.initializers,
    )
    onnx_model = helper.make_model(
        graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="tactile-handover", ir_version=IR_VERSION
    )
    props = {}
    if layout is not None and not layout.in_order:
        props[FEATURE_COLUMNS] = json.dumps([int(c) for c in layout.columns])
    if layout is not None and layout.scaled:
        props[FEATURE_SCALES] = json.dumps([float(s) for s in layout.scale_of_each()])
    if props:
        helper.set_model_props(onnx_model, props)
    return onnx_model


def feature_columns(proto) -> np.ndarray | None:
    """Where the ``histogram`` tensor of a graph holds each reference feature (None: in order);
    ValueError (one line, what to do) when the property is damaged."""
    columns = _json_property(proto, FEATURE_COLUMNS, lambda c: isinstance(c, list)
                             and all(isinstance(i, int) and i >= 0 for i in c) and len(set(c)) == len(c))
    return None if columns is None else np.asarray(columns, dtype=np.int64)


def feature_scales(proto) -> np.ndarray | None:
    """What each reference feature is multiplied by in the graph's ``histogram`` (None: 1), in the
    reference's order; ValueError (one line, what to do) when the property is damaged."""
    scales = _json_property(proto, FEATURE_SCALES, lambda v: isinstance(v, list)
                            and all(isinstance(x, int | float) and np.isfinite(x) and x != 0 for x in v))
    return None if scales is None else np.asarray(scales, dtype=np.float64)


def _json_property(proto, key: str, valid: Callable[[object], bool]):
    """The JSON value of model property ``key`` (None: absent); ValueError when it is not JSON or not
    ``valid``."""
    props = {p.key: p.value for p in proto.metadata_props}
    if key not in props:
        return None
    try:
        ok = valid(value := json.loads(props[key]))
    except (ValueError, OverflowError):
        ok = False
    if not ok:
        raise ValueError(f"model property {key} is damaged; re-export the model")
    return value


# -- metadata and file ----------------------------------------------------------------------------
def model_metadata(model, metadata: dict, fold_derivative: bool = False) -> dict:
    """Complete the caller's metadata (``trainer.model_meta``) with what the model itself
    determines; refuse contradictions."""
    from runtime.model import SCHEMA_VERSION
    from trainer.model_meta import defaults, provenance

    svm = model.svm_
    bow = getattr(model, "bow_", None)
    n_timepoints, n_channels = model_shape(model)
    feature_svc = hasattr(model, "onnx_features")
    windows = [int(w) for w, _, _ in bow.scales()] if bow is not None else []
    derived = {
        "schema_version": SCHEMA_VERSION,
        "classes": [str(c) for c in model.classes_],
        "T": n_timepoints,
        # a flattened-series SVM has no windows or words: 1 and 1 satisfy the contract's ranges
        "W": max(windows) if windows else 1,
        "K": int(bow.n_words) if bow is not None else 1,
        "n_channels": n_channels,
    }
    for key, value in derived.items():
        if key in metadata and metadata[key] != value:
            raise ValueError(f"metadata {key}={metadata[key]!r} contradicts the model ({value!r})")
    meta = {**defaults(), "score": SCORE_MEANING, **metadata, **derived}
    if "pad_sizes" not in meta:
        if feature_svc:
            meta["pad_sizes"] = [int(s) for s in (model.pad_sizes or [n_channels])]
        else:
            meta["pad_sizes"] = list(bow.pad_sizes_) if bow is not None and bow.per_pad else [n_channels]
    meta["training"] = provenance(meta.get("training"))
    meta["model_kind"] = "feature_svm" if feature_svc else "bow_svm" if bow is not None else "flat_svm"
    if feature_svc:
        meta["features"] = model.describe()
        meta["feature_groups"] = list(meta["pad_sizes"])
    elif bow is not None:
        meta["feature_groups"] = [int(s) for s in bow.pad_sizes_]
        meta["features"] = {
            "windows": windows,
            "assignment": str(getattr(bow, "assignment", "hard")),
            "temperatures": [float(t) for _, _, t in bow.scales()] if getattr(bow, "assignment", "hard") == "soft" else None,
            "level_features": bool(getattr(bow, "level_features", False)),
            "level_groups": [int(s) for s in getattr(bow, "level_groups_", ())],
            "scale_features": getattr(model, "scaler_", None) is not None,
            "n_features": int(bow.n_features_out_),
        }
    else:
        meta["features"] = {"flattened": "channel-major C x T, standardised", "n_features": n_timepoints * n_channels}
    meta["kernel"] = str(svm.kernel)
    meta["svm"] = {"C": float(svm.C), "gamma": float(getattr(svm, "_gamma", 0.0)), "n_support_vectors": int(sum(svm.n_support_))}
    meta["graph"] = {"opset": OPSET, "ir_version": IR_VERSION, "fold_derivative": bool(fold_derivative)}
    return meta


def export_onnx(model, path: str | Path, metadata: dict, fold_derivative: bool = False, early=None) -> Path:
    """Write the model as one ONNX file (atomically) and check it with the runtime's loader.

    ``early``: a ``trainer.early.EarlyHeads`` whose heads join the graph (``trainer.early_export``)
    and whose rule goes into the metadata (``runtime.early``)."""
    import onnx

    from runtime.early import EARLY_KEY
    from runtime.model import METADATA_KEY, ModelMeta, load_model

    meta = model_metadata(model, metadata, fold_derivative)
    if early is not None:
        meta[EARLY_KEY] = early.spec.to_meta()
    ModelMeta.from_dict(json.loads(json.dumps(meta)))
    onnx_model = build_graph(model, fold_derivative)
    if early is not None:
        from trainer.early_export import add_heads

        add_heads(onnx_model, model, early.models, early.spec.points, int(meta["T"]))
    props = {p.key: p.value for p in onnx_model.metadata_props}
    onnx.helper.set_model_props(onnx_model, {**props, METADATA_KEY: json.dumps(meta, sort_keys=True)})
    onnx.checker.check_model(onnx_model, full_check=True)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(onnx_model.SerializeToString())
            fh.flush()
            os.fsync(fh.fileno())
        load_model(tmp)
        os.chmod(tmp, 0o644)  # mkstemp makes 0600: the daemon's user must be able to read it
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path

