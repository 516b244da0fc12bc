"""The heap at start-up: collected once, and everything alive then hidden from the collector.

Why: the collector's older generations re-scan every long-lived object (modules, the model, the
config) when they run; ``gc.freeze`` takes those out of every later collection, so a collection
during a decision scans only what was allocated since (results/latency.md has the figures).
Automatic collection stays on: reference counting frees almost everything at once anyway, and
the collector is only for cycles.
"""

from __future__ import annotations

import gc

__all__ = ["settle_heap"]


def settle_heap() -> None:
    """Collect once and hide every object alive now from the collector (``gc.freeze``)."""
    gc.collect()
    gc.freeze()
