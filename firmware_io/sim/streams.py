"""Seeded random substreams: every subject, trial and hand gets its own, keyed by what it is.

Why: adding a trial or a subject must not change any other one, so no stream is shared and
nothing depends on the order things are generated in. ``np.random.SeedSequence`` with a
``spawn_key`` gives statistically independent streams from one user seed.
"""

from __future__ import annotations

import zlib

import numpy as np

__all__ = ["stream"]

_KINDS = {"hand": 1, "subject": 2, "trial": 3, "timing": 4, "script": 5, "event": 6}


def _word(part: object) -> int:
    if isinstance(part, (int, np.integer)):
        return int(part) & 0xFFFFFFFF
    return zlib.crc32(str(part).encode())


def stream(seed: int, kind: str, *key: object) -> np.random.Generator:
    """Generator for ``kind`` (hand, subject, trial, ...) identified by ``key`` under ``seed``."""
    words = (_KINDS[kind], *(_word(k) for k in key))
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(int(seed), spawn_key=words)))
