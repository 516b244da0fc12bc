"""The SVM head (trainer/svm_head.py): the expanded RBF kernel (folded or not) and the linear SVM with
the scaler in its weights keep their float32 decisions within the bound ``handover verify`` uses
(trainer/numerics.py), and features in the graph's own layout (unused columns, another order)
decide like the reference."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
import pytest

from runtime.model import session_options
from tests.onnx_fixtures import PAD_SIZES, T, frames_of, synthetic_cases
from trainer.feature_svc import FeatureSVC
from trainer.numerics import reference, svm_decision_bounds
from trainer.onnx_export import build_graph, feature_columns
from trainer.stress import stress_cases
from trainer.svm_head import FOLD_LIMIT, RbfConstants


def _decisions(model, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The graph's one-vs-one decisions (the first P columns of its decision Gemm) and labels."""
    proto = build_graph(model)
    name = next(n.output[0] for n in proto.graph.node if n.op_type == "Gemm" and n.output[0].startswith("decision"))
    proto.graph.output.append(onnx.helper.make_tensor_value_info(name, onnx.TensorProto.FLOAT, None))
    session = ort.InferenceSession(proto.SerializeToString(), session_options(), providers=["CPUExecutionProvider"])
    labels, dec = session.run(["label", name], {"frames": frames})
    n_classes = len(model.classes_)
    return dec[:, : n_classes * (n_classes - 1) // 2], labels


@pytest.mark.parametrize(("kernel", "gamma"), [("rbf", "scale"), ("rbf", 1.0), ("linear", "scale")],
                         ids=["rbf-folded", "rbf-offset-added", "linear-scaler-folded"])
def test_decisions_within_the_verify_bound(kernel, gamma):
    X, y = synthetic_cases(n=96, seed=3)
    model = FeatureSVC(families=("hand", "stats"), pad_sizes=PAD_SIZES, kernel=kernel, C=10.0, gamma=gamma,
                       feature_weighting="distinct").fit(X, y)
    if kernel == "rbf":
        rbf = RbfConstants.of(model.svm_, model.scaler_)
        assert rbf.folded == (gamma == "scale")  # gamma 1 puts gamma ||sv||^2 past FOLD_LIMIT
        assert rbf.folded or -rbf.offset.min() > FOLD_LIMIT
    stress = stress_cases(T, sum(PAD_SIZES), np.eye(2, 4) * 100.0, seed=2)
    frames = np.concatenate([frames_of(synthetic_cases(n=64, seed=9)[0]), *stress.values()])
    dec, labels = _decisions(model, frames)
    ref = reference(model, frames)
    assert np.isfinite(dec).all()
    excess = np.abs(dec.astype(np.float64) - ref["decisions"]) - ref["decision_bounds"]
    assert (excess <= 0).all(), excess.max()
    # the head's own share of the bound (exact features) is float32 rounding, not a blanket
    own = svm_decision_bounds(model.svm_, ref["hist"], None, model.scaler_)
    assert np.median(own / np.maximum(np.abs(ref["decisions"]), 1e-300)) < 1e-3 or not own.any()
    tie = np.abs(ref["decisions"]) <= ref["decision_bounds"]
    assert np.array_equal(labels[~tie.any(axis=1)], ref["labels"][~tie.any(axis=1)])


def test_graph_layout_differs_from_the_reference_order_and_decides_alike():
    X, y = synthetic_cases(n=96, seed=4)
    model = FeatureSVC(families=("stats", "hand"), pad_sizes=PAD_SIZES, kernel="rbf", C=10.0, gamma="scale").fit(X, y)
    proto = build_graph(model)
    columns = feature_columns(proto)
    n_features = model.scaler_.n_features_in_
    assert columns is not None and len(columns) == n_features and len(set(columns)) == n_features
    assert not np.array_equal(columns, np.arange(n_features))  # reordered, with unused columns in between
    assert columns.max() >= n_features
    frames = frames_of(synthetic_cases(n=48, seed=11)[0])
    _, labels = _decisions(model, frames)
    assert np.array_equal(model.classes_[labels], model.predict(frames.transpose(0, 2, 1).astype(np.float64)))


@pytest.mark.parametrize(("key", "value"), [("handover_feature_columns", v) for v in
                                             ("[0, 1", "{\"a\": 1}", "[0, 0, 1]", "[0, 99999]")]
                         + [("handover_feature_scales", v) for v in ("[1, 2", "\"x\"", "[1, 0]", "[1, NaN]", "[1, 2]")])
def test_a_damaged_feature_layout_is_one_clear_verify_error(key, value, tmp_path):
    """The graph's feature layout (columns, constant factors) is model properties; damaged, verify
    says so instead of a traceback."""
    from tests.onnx_fixtures import export
    from trainer.onnx_export import FEATURE_COLUMNS, FEATURE_SCALES
    from trainer.verify import GraphRunner, VerifyError

    X, y = synthetic_cases(n=40, seed=2)
    path = export(FeatureSVC(families=("hand", "stats"), pad_sizes=PAD_SIZES, kernel="linear", C=1.0).fit(X, y),
                  tmp_path)
    proto = onnx.load(str(path))
    props = {p.key: p.value for p in proto.metadata_props}
    # the hand family's layout is not the reference's order, and the level statistics' std is held times sqrt(T)
    assert FEATURE_COLUMNS in props and FEATURE_SCALES in props and key in (FEATURE_COLUMNS, FEATURE_SCALES)
    onnx.helper.set_model_props(proto, {**props, key: value})
    onnx.save(proto, str(path))
    with pytest.raises(VerifyError, match=rf"{key} .*re-export the model"):
        GraphRunner(path).run(frames_of(X))


def test_features_held_times_a_constant_are_read_back_in_the_reference_units(tmp_path):
    """Constant factors (the stats' std times sqrt(T), the peak times fullscale) sit in the SVM's
    weights instead of a Mul node; ``handover verify`` divides them out again."""
    from tests.onnx_fixtures import export
    from trainer.onnx_export import FEATURE_SCALES, feature_scales
    from trainer.verify import GraphRunner

    X, y = synthetic_cases(n=64, seed=6)
    for kernel in ("linear", "rbf"):
        model = FeatureSVC(families=("hand", "stats"), pad_sizes=PAD_SIZES, kernel=kernel, C=10.0,
                           gamma="scale" if kernel == "rbf" else None).fit(X, y)
        path = export(model, tmp_path, f"{kernel}.onnx")
        proto = onnx.load(str(path))
        scales = feature_scales(proto)
        assert FEATURE_SCALES in {p.key for p in proto.metadata_props} and (scales != 1).any()
        frames = frames_of(synthetic_cases(n=32, seed=12)[0])
        labels, _, features = GraphRunner(path).run(frames)
        cases = frames.transpose(0, 2, 1).astype(np.float64)
        excess = np.abs(features - model.transform_histograms(cases)) - model.feature_error_bounds(cases)
        assert (excess <= 0).all(), excess.max()
        assert np.array_equal(model.classes_[labels], model.predict(cases))
