"""The daemon's single-window run (``LoadedModel.run_trusted``) gives session.run's answers, one answer per
window wherever the ring holds it, answers the caller may keep; batches, other dtypes and a second
caller at the same time run as given."""

from __future__ import annotations

import numpy as np
import pytest

from runtime.model import INPUT_NAME, OUTPUT_NAMES, _aligned, load_model
from tests.tiny_models import tiny_model_bytes, write_model

T, C = 15, 234


def _windows(n: int) -> np.ndarray:
    return np.random.default_rng(0).uniform(0, 4095, (n, 1, T, C)).astype(np.float32)


@pytest.fixture
def model(tmp_path):
    return load_model(write_model(tmp_path, "m.onnx", tiny_model_bytes(weights=(1.0, -1.0, 0.5, 0.0))))


def test_answers_are_session_run_answers_bit_for_bit(model) -> None:
    for w in _windows(4):
        labels, scores = model.run_trusted(w)
        stage = _aligned((1, T, C))  # aligned as the staging array: the same sums
        stage[...] = w
        ref_labels, ref_scores = model._session.run(OUTPUT_NAMES, {INPUT_NAME: stage})
        assert np.array_equal(labels, ref_labels) and scores.tobytes() == ref_scores.tobytes()


def test_one_window_gives_one_answer_wherever_the_ring_holds_it(model) -> None:
    """onnxruntime's sums depend on the input's address (session.run on these views gives several last
    bits on x86-64); through the staging array they do not."""
    w = _windows(1)[0]
    ring = np.zeros(T * C + 16, dtype=np.float32)
    answers = set()
    for offset in range(16):
        view = ring[offset : offset + T * C].reshape(1, T, C)
        view[...] = w
        answers.add(model.run_trusted(view)[1].tobytes())
    assert len(answers) == 1


def test_an_answer_kept_by_the_caller_survives_the_next_run(model) -> None:
    first, second = _windows(2)
    _, scores = model.run_trusted(first)
    kept = scores.copy()
    model.run_trusted(second * 0.5)
    assert np.array_equal(scores, kept)


def test_batches_and_single_windows_agree(model) -> None:
    windows = _windows(6)[:, 0]
    batch_labels, batch_scores = model.run_trusted(windows)
    for i, w in enumerate(windows):
        labels, scores = model.run_trusted(w[None])
        assert labels[0] == batch_labels[i]
        np.testing.assert_allclose(scores[0], batch_scores[i], rtol=1e-6)


def test_a_second_caller_while_the_staging_array_is_in_use_runs_as_given(model) -> None:
    w = _windows(1)[0]
    expected = model.run_trusted(w)[1]
    assert model._staging.acquire(False)  # another thread in the middle of a run
    try:
        np.testing.assert_allclose(model.run_trusted(w)[1], expected, rtol=1e-6)
    finally:
        model._staging.release()


@pytest.mark.parametrize("other", [np.float64, np.int64])
def test_a_window_of_another_dtype_is_refused_by_onnxruntime(model, other) -> None:
    with pytest.raises(Exception, match=r"(?i)type"):
        model.run_trusted(np.zeros((1, T, C), dtype=other))


def test_a_nested_list_runs_as_onnxruntime_converts_it(model) -> None:
    """``run(x, check=False)`` is ``run_trusted``: a nested list runs (onnxruntime converts it)."""
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
    """The output check refuses the answer in one line; onnxruntime prints nothing of its own."""
    from runtime.model import ModelContractError

    with pytest.raises(ModelContractError, match=r"scores output is float32 \[1, 5\], expected float \[1, 4\]"):
        load_model(write_model(tmp_path, "wide.onnx", _wider_scores_than_declared()))
    assert "onnxruntime" not in capfd.readouterr().err
