"""A model's decision in plain numpy, read from its exported graph: the latency benchmark's yardstick.

Why: onnxruntime's share of a decision is measured against what the same arithmetic costs without
it, in the same run (a ratio holds on a noisy machine where absolute figures do not). One module
per kind of graph: ``numpy_features`` (the default: hand + stats features, scaler, linear or RBF SVM) and
``numpy_bow`` (the BoW default before it); ``numpy_decision(path)`` picks the one that reads the
graph, or returns None where none does.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from trainer.bench.numpy_bow import NumpyBow
from trainer.bench.numpy_features import NumpyFeatures
from trainer.bench.numpy_graph import GraphParts

Decide = Callable[[np.ndarray], tuple[int, np.ndarray]]
"""``(window [T, C] float32) -> (label index, scores [n_classes])``."""


def numpy_decision(path: str | Path) -> Decide | None:
    """The numpy-only decision of the graph at ``path``, or None for a kind not implemented here."""
    parts = GraphParts.load(path)
    for kind in (NumpyFeatures, NumpyBow):
        decide = kind.of(parts)
        if decide is not None:
            return decide
    return None
