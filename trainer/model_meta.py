"""The metadata a model file carries besides what its estimator determines, built in one place.

Every exporter states the same keys (pads, trigger, frame rate, provenance, evaluation) through
``file_metadata``; ``trainer.onnx_export`` adds what the estimator determines and fills a key the
caller left out from ``defaults()``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import Any

from firmware_io.frame_timing import NOMINAL_RATE_HZ
from runtime.trigger_settings import PAPER_FRACTION

__all__ = ["dataset_metadata", "defaults", "file_metadata", "provenance"]

DEFAULT_FULLSCALE = 4095.0
"""The SDH-2 pads' 12-bit full scale, for a model whose maker did not record one."""


def defaults() -> dict[str, Any]:
    """What a model file records when its maker did not say: the SDH-2's full scale, the paper's
    threshold trigger, the pads' nominal frame rate, no dormant class, no evaluation."""
    return {"fullscale": DEFAULT_FULLSCALE, "trigger": {"fraction": PAPER_FRACTION},
            "sample_rate_hz": NOMINAL_RATE_HZ, "dormant_class": None, "evaluation": {}}


def provenance(training: dict | None = None) -> dict[str, Any]:
    """The ``training`` object: project version and date, then the caller's keys (which win)."""
    from runtime import __version__

    return {"project_version": __version__, "date": time.strftime("%Y-%m-%dT%H:%M:%S%z"), **(training or {})}


def file_metadata(*, pads: Sequence[int], pad_sizes: Sequence[int], training: dict,
                  fullscale: float | None = None, trigger: dict | None = None, sample_rate_hz: float | None = None,
                  evaluation: dict | None = None, dormant_class: str | None = None) -> dict[str, Any]:
    """A model's metadata for ``onnx_export.export_onnx``; None (or an unknown, NaN rate) takes ``defaults()``."""
    meta = defaults()
    given = {"fullscale": fullscale, "trigger": trigger, "sample_rate_hz": sample_rate_hz}
    meta.update({k: v for k, v in given.items() if v is not None and not (isinstance(v, float) and math.isnan(v))})
    meta["fullscale"] = float(meta["fullscale"])
    meta["trigger"] = dict(meta["trigger"])
    meta["sample_rate_hz"] = float(meta["sample_rate_hz"])
    return {"pads": [int(p) for p in pads], "pad_sizes": [int(s) for s in pad_sizes], **meta,
            "dormant_class": dormant_class, "training": provenance(training), "evaluation": dict(evaluation or {})}


def dataset_metadata(ds, training: dict, evaluation: dict | None = None, dormant_class: str | None = None
                     ) -> dict[str, Any]:
    """``file_metadata`` of a model trained on the data set ``ds`` (a ``trainer.dataset.Dataset``
    or anything with its pads, trigger, rate, fingerprint and ``counts()``)."""
    return file_metadata(
        pads=ds.pads, pad_sizes=ds.pad_sizes, fullscale=ds.fullscale, trigger=ds.trigger.to_meta(),
        sample_rate_hz=ds.sample_rate_hz, evaluation=evaluation, dormant_class=dormant_class,
        training={"data_fingerprint": ds.fingerprint, **ds.counts().to_meta(), **training})
