"""Offline training: dataset assembly, Bag-of-Words + SVM, evaluation, report, ONNX export."""

import runtime  # noqa: F401  (before any onnxruntime import: it turns onnxruntime's telemetry off)

__all__ = ["default_classifier"]


def default_classifier(pad_sizes, pad_shapes=None, random_state: int = 0, fullscale: float = 4095.0):
    """The product's default estimator, unfitted (see ``trainer.defaults``)."""
    from trainer.defaults import default_classifier as build

    return build(pad_sizes, pad_shapes=pad_shapes, random_state=random_state, fullscale=fullscale)
