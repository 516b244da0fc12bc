"""The batched feature graph (issue #16: all pads in one tensor, one TopK, an exact If for a zero
median) against the per-pad graph it replaced: same labels, scores within float32 rounding, on
SDH-2-shaped windows through both branches of the median, and both against the float64 reference."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
import pytest

from runtime.model import session_options
from tests.legacy_feature_graph import legacy_hand_nodes, legacy_stats_peak
from tests.onnx_fixtures import T, frames_of, synthetic_cases
from trainer.feature_svc import FeatureSVC
from trainer.features import HandGraphFeatures, PadStats
from trainer.features.base import OnnxParts
from trainer.features.pad_batch import PadBatch
from trainer.onnx_export import build_graph, feature_columns, feature_scales
from trainer.stress import stress_cases

SDH2_SIZES = (84, 78, 84, 78, 84, 78)
SDH2_SHAPES = [(14, 6), (13, 6)] * 3


class _Session:
    """A session that also outputs the features (``histogram``, in the reference's order and units)."""

    def __init__(self, proto) -> None:
        self.columns, self.scales = feature_columns(proto), feature_scales(proto)
        proto.graph.output.append(onnx.helper.make_tensor_value_info("histogram", onnx.TensorProto.FLOAT, None))
        self.session = ort.InferenceSession(proto.SerializeToString(), session_options(),
                                            providers=["CPUExecutionProvider"])

    def run(self, names: list[str], feeds: dict) -> list[np.ndarray]:
        out = self.session.run(names, feeds)
        return [self._features(o) if n == "histogram" else o for n, o in zip(names, out, strict=True)]

    def _features(self, hist: np.ndarray) -> np.ndarray:
        hist = hist if self.columns is None else hist[:, self.columns]
        return hist if self.scales is None else hist / self.scales



def _legacy_hand_parts(family, g, frames: str) -> OnnxParts:
    return OnnxParts.in_order([legacy_hand_nodes(family, g, frames)], family.n_features_out_)


def _both_graphs(model, monkeypatch):
    new = _Session(build_graph(model))
    with monkeypatch.context() as m:
        m.setattr(HandGraphFeatures, "onnx_parts", _legacy_hand_parts)
        m.setattr(PadStats, "_peak_nodes", legacy_stats_peak)
        old_proto = build_graph(model)
    assert len(old_proto.graph.node) > 2 * len(build_graph(model).graph.node)
    old = _Session(old_proto)
    return old, new


def _sdh2_windows(n: int, seed: int, touched: float) -> np.ndarray:
    """float32 ``[n, T, 486]`` 12-bit windows with a share ``touched`` of taxels pressed."""
    rng = np.random.default_rng(seed)
    x = rng.integers(0, 4096, (n, T, sum(SDH2_SIZES))) * (rng.random((n, 1, sum(SDH2_SIZES))) < touched)
    return x.astype(np.float32)


@pytest.fixture(scope="module")
def sdh2_model():
    rng = np.random.default_rng(0)
    X = np.concatenate([_sdh2_windows(40, 1, 0.2), _sdh2_windows(40, 2, 0.8)]).transpose(0, 2, 1)
    y = np.array(["pull", "push", "hold", "bump"])[rng.integers(0, 4, len(X))]
    X[y == "push"] *= 0.5  # something to learn
    return FeatureSVC(pad_sizes=SDH2_SIZES, pad_shapes=SDH2_SHAPES, C=10.0, gamma="scale").fit(X.astype(np.float64), y)


def test_batched_graph_decides_like_the_per_pad_graph(sdh2_model, monkeypatch):
    old, new = _both_graphs(sdh2_model, monkeypatch)
    sparse, dense = _sdh2_windows(60, 5, 0.15), _sdh2_windows(60, 6, 0.9)  # a zero median; the TopK branch
    negative = -_sdh2_windows(10, 7, 0.9)  # below zero: the If must not take the zero branch
    for frames in (sparse, dense, negative, np.concatenate([sparse[:5], dense[:5]])):
        (old_labels, old_scores), (new_labels, new_scores) = (s.run(["label", "scores"], {"frames": frames})
                                                              for s in (old, new))
        assert np.array_equal(old_labels, new_labels)
        np.testing.assert_allclose(new_scores, old_scores, rtol=0, atol=1e-4)
        (old_hist,), (new_hist,) = (s.run(["histogram"], {"frames": frames}) for s in (old, new))
        np.testing.assert_allclose(new_hist, old_hist, rtol=1e-5, atol=1e-3)
    labels = new.run(["label"], {"frames": dense})[0]
    assert np.array_equal(sdh2_model.classes_[labels], sdh2_model.predict(dense.transpose(0, 2, 1)))


@pytest.mark.parametrize("pad_sizes", [(6, 10), (6, 9), (8, 8)], ids=["even-padding", "odd-padding", "same-size"])
def test_median_by_pad_against_numpy(pad_sizes):
    """One TopK for all pads (even padding), one per pad (odd padding), no padding; both If branches."""
    X, y = synthetic_cases(n=48, seed=4)
    X = X[:, : sum(pad_sizes)] if sum(pad_sizes) <= X.shape[1] else np.concatenate([X, X], axis=1)[:, : sum(pad_sizes)]
    family = HandGraphFeatures(pad_sizes=pad_sizes).fit(X)
    model = FeatureSVC(families=("hand",), pad_sizes=pad_sizes, C=10.0, gamma="scale").fit(X, y)
    session = _Session(build_graph(model))
    zero_mostly = X * (np.arange(X.shape[1]) % 3 == 0)[None, :, None]  # a third of each pad touched: no TopK
    stress = np.concatenate(list(stress_cases(T, sum(pad_sizes), np.eye(2, 4) * 100.0, seed=1).values()))
    for frames in (frames_of(X), frames_of(zero_mostly), frames_of(-X), stress):
        (hist,) = session.run(["histogram"], {"frames": frames})
        ref = family.transform(frames.transpose(0, 2, 1).astype(np.float64))
        np.testing.assert_allclose(hist[:, 2::14], ref[:, 2::14], rtol=1e-6, atol=1e-3)  # the medians
    assert PadBatch.of([(1, s) for s in pad_sizes]).median_in_one == (len(set(np.array(pad_sizes) % 2)) == 1)


@pytest.mark.parametrize(("pad_shapes", "budget"), [([(13, 6)] * 3, 49), (SDH2_SHAPES, 52)], ids=["distal", "all-pads"])
def test_default_graph_node_budget(pad_shapes, budget):
    """onnxruntime pays per node (issue #16): the default's graph keeps its count (distal 62 and all
    pads 63 before the hand and stats families shared one series pipeline and constant factors moved
    into the SVM's weights)."""
    sizes = [r * c for r, c in pad_shapes]
    rng = np.random.default_rng(3)
    X = rng.integers(0, 4096, (24, sum(sizes), T)) * (rng.random((24, sum(sizes), 1)) < 0.3)
    y = np.array(["pull", "push", "hold", "bump"])[np.arange(24) % 4]
    model = FeatureSVC(pad_sizes=sizes, pad_shapes=pad_shapes, kernel="linear", C=1.0,
                       feature_weighting="distinct").fit(X.astype(np.float64), y)
    ops = [n.op_type for n in build_graph(model).graph.node]
    assert len(ops) <= budget, ops
    assert ops.count("ReduceMean") == 1 and "Transpose" in ops  # one series pipeline; one layout change


def test_join_parts_reads_a_shared_tensor_once_unless_its_columns_are_taken():
    from trainer.features.base import join_parts

    first = OnnxParts(["rows", "peak"], np.array([0, 2, 4]), 5, None, (4, 1))  # rows 0 and 2, the peak
    second = OnnxParts(["rows", "peak"], np.array([1, 3, 4]), 5, np.array([1.0, 2.0, 3.0]), (4, 1))
    joined = join_parts([first, second])
    assert joined.tensors == ["rows", "peak", "peak"]  # rows shared (other columns), the peak's column taken
    assert joined.columns.tolist() == [0, 2, 4, 1, 3, 5] and joined.width == 6
    assert joined.scales.tolist() == [1, 1, 1, 1, 2, 3]
    alone = join_parts([OnnxParts.in_order(["bow"], 3), first])  # parts without widths are one block
    assert alone.tensors == ["bow", "rows", "peak"] and alone.columns.tolist() == [0, 1, 2, 3, 5, 7]
