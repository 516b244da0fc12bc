"""Keep Python's cyclic garbage collector off the hot path.

Why: a full collection walks every object the process holds (onnxruntime's and numpy's modules,
the model, the config): milliseconds, at a moment nobody chooses, so it lands in a decision now
and then and is the tail of the latency figures. Objects that live as long as the serving model
are moved out of the collector's sight once, when a model starts serving; the per-frame garbage
(frames, events) is young and stays cheap to collect.
"""

from __future__ import annotations

import gc


def settle_heap() -> None:
    """Collect everything once (frozen objects too: a swapped-out model in a reference cycle is
    freed here, not leaked), then freeze what survives (``gc.freeze``): later collections skip it."""
    gc.unfreeze()
    gc.collect()
    gc.freeze()
