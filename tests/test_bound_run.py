"""The daemon's single-window run through bound buffers gives session.run's answers, never shares them,
and steps aside (None) for batches, a second caller and graphs whose outputs do not fit."""

from __future__ import annotations

import numpy as np
import onnxruntime as ort
import pytest

from runtime.bound_run import BoundRun
from runtime.model import INPUT_NAME, OUTPUT_NAMES, load_model
from tests.tiny_models import tiny_model_bytes, write_model

T, C, N_CLASSES = 15, 234, 4


def _session(data: bytes):
    return ort.InferenceSession(data, providers=["CPUExecutionProvider"])


def _bound(data: bytes) -> tuple[BoundRun, object]:
    session = _session(data)
    return BoundRun(session, INPUT_NAME, OUTPUT_NAMES, (T, C), N_CLASSES), session


def _windows(n: int) -> np.ndarray:
    return np.random.default_rng(0).uniform(0, 4095, (n, 1, T, C)).astype(np.float32)


def test_bound_answers_are_session_run_answers_bit_for_bit() -> None:
    bound, session = _bound(tiny_model_bytes(weights=(1.0, -1.0, 0.5, 0.0)))
    for w in _windows(20):
        labels, scores = bound.run(w)
        ref_labels, ref_scores = session.run(OUTPUT_NAMES, {INPUT_NAME: w.copy()})  # a fresh, aligned array
        assert labels.dtype == np.int64 and scores.dtype == np.float32
        assert np.array_equal(labels, ref_labels) and np.array_equal(scores, ref_scores)


def test_one_window_gives_one_answer_wherever_the_ring_holds_it() -> None:
    """onnxruntime's sums depend on the input's address (session.run on these views gives several last
    bits on x86-64); through the staging array they do not."""
    bound, session = _bound(tiny_model_bytes(weights=(1.0, -1.0, 0.5, 0.0)))
    w = _windows(1)[0]
    ring = np.zeros(T * C + 16, dtype=np.float32)
    bound_answers = set()
    for offset in range(16):
        view = ring[offset : offset + T * C].reshape(1, T, C)
        view[...] = w
        bound_answers.add(bound.run(view)[1].tobytes())
    assert len(bound_answers) == 1
    assert session.run(OUTPUT_NAMES, {INPUT_NAME: w.copy()})[1].tobytes() in bound_answers


def test_an_answer_kept_by_the_caller_survives_the_next_run() -> None:
    bound, _ = _bound(tiny_model_bytes(weights=(1.0, -1.0, 0.5, 0.0)))
    first, second = _windows(2)
    _, scores = bound.run(first)
    kept = scores.copy()
    bound.run(second * 0.5)
    assert np.array_equal(scores, kept)


def test_a_batch_or_another_shape_is_left_to_session_run() -> None:
    bound, _ = _bound(tiny_model_bytes())
    assert bound.run(np.zeros((3, T, C), np.float32)) is None
    assert bound.run(np.zeros((1, T - 1, C), np.float32)) is None
    assert not bound.broken


def test_a_second_caller_while_the_binding_is_in_use_is_left_to_session_run() -> None:
    bound, _ = _bound(tiny_model_bytes())
    assert bound._lock.acquire(False)  # another thread in the middle of a bound run
    try:
        assert bound.run(_windows(1)[0]) is None
    finally:
        bound._lock.release()
    assert bound.run(_windows(1)[0]) is not None


def test_a_graph_whose_scores_do_not_fit_the_bound_buffer_falls_back_for_good() -> None:
    import onnx

    model = onnx.load_from_string(tiny_model_bytes(classes=("pull", "push", "hold", "bump", "spare")))
    model.graph.output[1].type.tensor_type.shape.dim[1].dim_value = N_CLASSES  # says 4, gives 5
    bound, session = _bound(model.SerializeToString())
    assert bound.run(_windows(1)[0]) is None and bound.broken
    _, scores = session.run(OUTPUT_NAMES, {INPUT_NAME: _windows(1)[0]})
    assert scores.shape == (1, 5)  # what the output contract check then refuses, with its own message


def test_the_loaded_model_runs_bound_and_batches_alike(tmp_path) -> None:
    model = load_model(write_model(tmp_path, "m.onnx", tiny_model_bytes(weights=(1.0, -1.0, 0.5, 0.0))))
    windows = _windows(6)[:, 0]
    batch_labels, batch_scores = model.run_trusted(windows)
    for i, w in enumerate(windows):
        labels, scores = model.run_trusted(w[None])
        assert labels[0] == batch_labels[i]
        np.testing.assert_allclose(scores[0], batch_scores[i], rtol=1e-6)
    assert not model._bound.broken


@pytest.mark.parametrize("other", [np.float64, np.int64])
def test_a_window_of_another_dtype_is_left_to_session_run_which_refuses_it(other) -> None:
    bound, session = _bound(tiny_model_bytes())
    w = np.zeros((1, T, C), dtype=other)
    assert bound.run(w) is None and not bound.broken
    with pytest.raises(Exception, match=r"(?i)type"):
        session.run(OUTPUT_NAMES, {INPUT_NAME: w})


def test_a_nested_list_is_left_to_session_run_which_converts_it(tmp_path) -> None:
    """``run(x, check=False)`` is ``run_trusted``; before the binding a nested list ran (onnxruntime
    converts it), and the binding must not turn it into an AttributeError ('list' has no 'shape')."""
    model = load_model(write_model(tmp_path, "m.onnx", tiny_model_bytes(weights=(1.0, -1.0, 0.5, 0.0))))
    window = _windows(1)[0]
    labels, scores = model.run(window.tolist(), check=False)
    ref_labels, ref_scores = model.run_trusted(window)
    assert np.array_equal(labels, ref_labels)
    np.testing.assert_allclose(scores, ref_scores, rtol=1e-6)


def _wider_scores_than_declared() -> bytes:
    """A tiny model whose ``scores`` gets one more column at run time than its declared (and inferred)
    width: the extra column's shape comes from the batch size, so shape inference cannot see it."""
    import onnx
    from onnx import helper, numpy_helper

    model = onnx.load_from_string(tiny_model_bytes())
    for node in model.graph.node:
        node.output[:] = ["scores_raw" if o == "scores" else o for o in node.output]
        node.input[:] = ["scores_raw" if i == "scores" else i for i in node.input]
    model.graph.initializer.extend([numpy_helper.from_array(np.zeros((1, 1), np.float32), "zero"),
                                    numpy_helper.from_array(np.array([1], np.int64), "one")])
    model.graph.node.extend([
        helper.make_node("Shape", ["scores_raw"], ["rows"], start=0, end=1),
        helper.make_node("Concat", ["rows", "one"], ["column_shape"], axis=0),
        helper.make_node("Expand", ["zero", "column_shape"], ["column"]),
        helper.make_node("Concat", ["scores_raw", "column"], ["scores"], axis=1),
    ])
    return model.SerializeToString()


def test_a_graph_wider_than_declared_is_refused_in_one_line_without_onnxruntimes_own_error(tmp_path, capfd) -> None:
    """The bound run fails (its buffer has the declared width) and session.run's answer is refused by
    the output check; onnxruntime printed a multi-line coloured ERROR to stderr before that one line."""
    from runtime.model import ModelContractError

    with pytest.raises(ModelContractError, match=r"scores output is float32 \[1, 5\], expected float \[1, 4\]"):
        load_model(write_model(tmp_path, "wide.onnx", _wider_scores_than_declared()))
    assert "onnxruntime" not in capfd.readouterr().err
