"""The exported graph reproduces BowSVC (labels, scores, histograms) with standard operators only."""

from __future__ import annotations

import joblib
import numpy as np
import onnx
import pytest

from runtime.cli import main as handover
from runtime.model import load_model
from tests.onnx_fixtures import export, fit_model, frames_of, synthetic_cases
from trainer.onnx_export import IR_VERSION, OPSET, export_onnx
from trainer.verify import GraphRunner


@pytest.fixture(scope="module")
def rbf_model():
    return fit_model("rbf", per_pad=True)


@pytest.fixture(scope="module")
def rbf_path(rbf_model, tmp_path_factory):
    return export(rbf_model, tmp_path_factory.mktemp("rbf"))


def _indices(model, X):
    return np.searchsorted(model.classes_, model.predict(X))


@pytest.mark.parametrize(("kernel", "per_pad", "fold"), [("rbf", True, False), ("rbf", False, False),
                                                          ("linear", True, False), ("rbf", True, True)])
def test_graph_matches_estimator(kernel, per_pad, fold, tmp_path):
    model = fit_model(kernel, per_pad=per_pad)
    path = export(model, tmp_path, fold_derivative=fold)
    X, _ = synthetic_cases(n=64, seed=7)
    labels, scores, hist = GraphRunner(path).run(frames_of(X))
    np.testing.assert_array_equal(labels, _indices(model, X))
    np.testing.assert_allclose(scores, model.decision_function(X), atol=1e-4)
    np.testing.assert_allclose(hist, model.bow_.transform(X), atol=1e-6)
    assert labels.dtype == np.int64 and scores.dtype == np.float32


def test_two_classes(tmp_path):
    model = fit_model("rbf", n_classes=2)
    path = export(model, tmp_path)
    X, _ = synthetic_cases(n=40, seed=3, n_classes=2)
    labels, scores = load_model(path).run(frames_of(X))
    np.testing.assert_array_equal(labels, _indices(model, X))
    assert scores.shape == (40, 2)
    # sklearn's binary decision_function is > 0 for classes_[1]; the ovr score of class 1 wins then
    dec = model.decision_function(X)
    assert np.all((scores[:, 1] > scores[:, 0]) == (dec > 0))


def test_standard_domains_opset_and_dynamic_batch(rbf_path, rbf_model):
    proto = onnx.load(str(rbf_path))
    onnx.checker.check_model(proto, full_check=True)
    assert proto.ir_version == IR_VERSION
    assert {(o.domain, o.version) for o in proto.opset_import} == {("", OPSET)}
    ops = {n.op_type for n in proto.graph.node}
    assert all(n.domain == "" for n in proto.graph.node)
    assert "SVMClassifier" not in ops and "Conv" in ops and "ArgMin" in ops
    assert proto.graph.input[0].type.tensor_type.shape.dim[0].dim_param == "N"
    model = load_model(rbf_path)
    X, _ = synthetic_cases(n=37, seed=11)
    for n in (1, 37):
        labels, scores = model.run(frames_of(X[:n]))
        assert labels.shape == (n,) and scores.shape == (n, 4)


def test_metadata_complete_and_derived(rbf_path, rbf_model):
    meta = load_model(rbf_path).meta
    assert meta.classes == tuple(str(c) for c in rbf_model.classes_)
    assert (meta.T, meta.W, meta.K, meta.n_channels) == (12, 5, 6, 16)
    assert meta.extra["feature_groups"] == [6, 10]
    assert meta.extra["kernel"] == "rbf"
    assert meta.training["data_fingerprint"] == "synthetic-test"


def test_metadata_defaults_come_from_model_meta(rbf_path, rbf_model, tmp_path):
    """A key the maker left out (or an unknown, NaN frame rate) takes trainer.model_meta's default:
    the paper's threshold and the pads' nominal rate; the caller's own keys win."""
    from runtime.trigger_settings import PAPER_FRACTION, resolve_trigger
    from trainer.model_meta import file_metadata

    plain = load_model(rbf_path).meta  # exported with pads and training only
    assert plain.trigger == {"fraction": PAPER_FRACTION} and plain.sample_rate_hz == 32.0
    assert plain.training["project_version"] and plain.training["date"]
    meta = file_metadata(pads=[1, 3], pad_sizes=[6, 10], sample_rate_hz=float("nan"), trigger={"fraction": 0.2},
                         training={"data_fingerprint": "x", "n_trials": 1, "date": "2026-01-01"})
    made = load_model(export_onnx(rbf_model, tmp_path / "m.onnx", meta)).meta
    assert made.sample_rate_hz == 32.0 and made.training["date"] == "2026-01-01"
    assert resolve_trigger(None, made.trigger).fraction == 0.2


def test_metadata_contradicting_the_model_is_refused(rbf_model, tmp_path):
    with pytest.raises(ValueError, match="T=99 contradicts"):
        export_onnx(rbf_model, tmp_path / "m.onnx", {"T": 99, "pads": [1, 3], "pad_sizes": [6, 10],
                                                     "training": {"data_fingerprint": "x", "n_trials": 1}})
    assert not (tmp_path / "m.onnx").exists()


def test_export_cli(rbf_model, tmp_path, capsys):
    src = tmp_path / "trained.joblib"
    joblib.dump({"model": rbf_model, "metadata": {"training": {"data_fingerprint": "f", "n_trials": 3}}}, src)
    assert handover(["export", str(src), "--out", str(tmp_path / "m.onnx"), "--pads", "1,3"]) == 2  # 16 != 156 taxels
    assert "trained on 16" in capsys.readouterr().err
    joblib.dump({"model": rbf_model, "metadata": {"pads": [1, 3], "pad_sizes": [6, 10],
                                                  "training": {"data_fingerprint": "f", "n_trials": 3}}}, src)
    assert handover(["export", str(src), "--out", str(tmp_path / "m.onnx")]) == 0
    wrote = capsys.readouterr().out
    assert "T=12, features: 6 words of W=5 derivative steps" in wrote, wrote  # what this BoW model has
    meta = load_model(tmp_path / "m.onnx").meta
    assert meta.extra["reference"]["file"] == "trained.joblib"
    (tmp_path / "junk.joblib").write_bytes(b"not a pickle")
    assert handover(["export", str(tmp_path / "junk.joblib")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("handover export: ") and "Traceback" not in err
    assert err.strip().endswith(f"give the .joblib that train wrote (e.g. {tmp_path / 'model.joblib'})")


def test_export_of_the_onnx_model_says_to_give_the_joblib(rbf_model, tmp_path, capsys):
    """`handover export report/model.onnx` said `not a readable joblib file (KeyError: 8)`, exit 1."""
    src = tmp_path / "model.joblib"
    joblib.dump({"model": rbf_model, "metadata": {"pads": [1, 3], "pad_sizes": [6, 10]}}, src)
    assert handover(["export", str(src)]) == 0
    capsys.readouterr()
    onnx_path = tmp_path / "model.onnx"
    before = onnx_path.read_bytes()
    assert handover(["export", str(onnx_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"handover export: {onnx_path}: this is an ONNX model (what export writes), not a trained model; "
                   f"give the .joblib that train wrote (e.g. {src})")
    assert onnx_path.read_bytes() == before  # nothing overwritten


def _onehot_chain(path, tmp_path):
    """The graph as exported before issue #16 (ArgMin -> OneHot -> ReduceSum over windows): the
    word counts of the plane-wise Equal chain must be the same numbers, ties included."""
    from onnx import helper, numpy_helper

    proto = onnx.load(str(path))
    nodes = list(proto.graph.node)
    start = next(i for i, n in enumerate(nodes) if n.op_type == "ArgMin")
    stop = next(i for i, n in enumerate(nodes) if n.op_type == "Transpose" and n.output[0].startswith("per_channel"))
    words, per_channel = nodes[start].output[0], nodes[stop].output[0]
    proto.graph.initializer.extend([numpy_helper.from_array(np.array(6, np.int64), "old_depth"),
                                    numpy_helper.from_array(np.array([0.0, 1.0], np.float32), "old_onoff"),
                                    numpy_helper.from_array(np.array([1], np.int64), "old_axis1")])
    old = [helper.make_node("OneHot", [words, "old_depth", "old_onoff"], ["old_onehot"], axis=-1),
           helper.make_node("ReduceSum", ["old_onehot", "old_axis1"], [per_channel], keepdims=0)]
    del proto.graph.node[:]
    proto.graph.node.extend(nodes[: start + 1] + old + nodes[stop + 1 :])
    out = tmp_path / "onehot.onnx"
    onnx.save(proto, str(out))
    return out


def test_word_counts_same_as_the_onehot_graph_with_ties(tmp_path):
    model = fit_model("rbf", per_pad=True)
    model.bow_.codebook_[1] = model.bow_.codebook_[0]  # every window ties words 0 and 1: ArgMin takes 0
    path = export(model, tmp_path)
    assert "OneHot" not in {n.op_type for n in onnx.load(str(path)).graph.node}
    X, _ = synthetic_cases(n=64, seed=3)
    new = GraphRunner(path).run(frames_of(X))
    old = GraphRunner(_onehot_chain(path, tmp_path)).run(frames_of(X))
    for a, b in zip(new, old, strict=True):
        np.testing.assert_array_equal(a, b)  # labels, scores and histograms: the same numbers
    np.testing.assert_allclose(new[2], model.bow_.transform(X), atol=1e-6)
