"""The output contract check: every hostile answer is caught, fast path or not."""

from __future__ import annotations

import numpy as np
import pytest

from runtime.output_check import output_problem

GOOD_SCORES = np.array([[0.1, 2.0, -1.5, 0.0]], dtype=np.float32)


def _one(label=1, scores=GOOD_SCORES, label_dtype=np.int64):
    return np.array([label], dtype=label_dtype), scores


@pytest.mark.parametrize("labels, scores", [
    _one(), _one(label=0), _one(label=3), _one(label_dtype=np.int32),  # int32 labels: the full check's case
    _one(scores=GOOD_SCORES.astype(np.float64)), _one(scores=np.full((1, 4), 3e38, np.float32)),
    (np.array([0, 3]), np.zeros((2, 4), np.float32)),
])
def test_good_answers_pass(labels, scores):
    assert output_problem(labels, scores, 4) is None


@pytest.mark.parametrize("labels, scores, says", [
    (*_one(scores=np.array([[0.1, np.nan, 0.0, 0.0]], np.float32)), "NaN"),
    (*_one(scores=np.array([[np.inf, 0.0, 0.0, 0.0]], np.float32)), "infinity"),
    (*_one(scores=np.array([[0.0, 0.0, 0.0, -np.inf]], np.float32)), "infinity"),
    (*_one(scores=np.array([[np.nan, 0.0, 0.0, 0.0]], np.float64)), "NaN"),
    (*_one(label=4), "outside 0..3"),
    (*_one(label=-1), "outside 0..3"),
    (*_one(label=7, label_dtype=np.int32), "outside 0..3"),
    (np.array([0, 9]), np.zeros((2, 4), np.float32), "label 9"),
    (np.array([1.0]), GOOD_SCORES, "label output is float64"),
    (np.array([[1]]), GOOD_SCORES, "expected int64 [N]"),
    (*_one(scores=np.zeros((1, 3), np.float32)), "scores output is float32 [1, 3]"),
    (*_one(scores=np.zeros((1, 4), np.int64)), "scores output is int64"),
    ([1], [[0.0, 0.0, 0.0, np.nan]], "NaN"),  # not arrays at all: the full check still reads them
])
def test_hostile_answers_are_caught(labels, scores, says):
    problem = output_problem(labels, scores, 4)
    assert problem is not None and says in problem
