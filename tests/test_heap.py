"""The serving model's objects leave the collector's walk, and a swapped-out model is still freed."""

from __future__ import annotations

import gc
import weakref

from runtime.heap import settle_heap


class _Cyclic:
    def __init__(self) -> None:
        self.me = self  # a reference cycle: only the cyclic collector frees it


def test_settle_heap_freezes_survivors_and_frees_what_was_frozen_before():
    try:
        old = _Cyclic()
        gone = weakref.ref(old)
        settle_heap()
        assert gc.get_freeze_count() > 0 and gone() is not None
        del old  # a model swapped out while frozen, kept alive only by its own cycle
        gc.collect()
        assert gone() is not None  # frozen objects are out of the ordinary collections' sight ...
        settle_heap()
        assert gone() is None  # ... and the next swap frees it
    finally:
        gc.unfreeze()
