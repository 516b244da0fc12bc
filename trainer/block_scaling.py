"""Multi-block scaling: how much each feature family weighs in the SVM's distance.

After one StandardScaler every non-constant feature has unit variance, so a family's share of the
squared RBF distance grows with how many features it has and how redundant they are. Two fixed
(not searched) ways to give every family the same say, computed on the training cases only:

- ``"count"``: divide each standardised block by sqrt(its non-constant features), so every block's
  total variance is 1 (constant features are zero after scaling and count for nothing);
- ``"mfa"``: divide each standardised block by sqrt(the largest eigenvalue of its covariance), as
  Multiple Factor Analysis does (Escofier & Pages 1994; Abdi, Williams & Valentin 2013): every
  block's first principal direction then has unit variance, so a family of many features that all
  say the same (e.g. several pressure levels) does not outweigh a family of a few independent ones.

The weights are folded into the scaler (``scale_ / weight``), so the exported graph, its float64
reference and the float32 bounds of ``handover verify`` stay the scaler's own.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

BLOCK_SCALINGS = (None, "count", "mfa")


def check_block_scaling(how) -> None:
    """One clear error for an unknown ``block_scaling``."""
    if how not in BLOCK_SCALINGS:
        raise ValueError(f"block_scaling must be one of {BLOCK_SCALINGS}, got {how!r}")


def block_weights(scaled: np.ndarray, sizes: Sequence[int], how: str | None) -> np.ndarray:
    """One weight per feature (``(F,)``) for the standardised training features ``scaled`` ``(n, F)``
    whose blocks have ``sizes`` features each, in order; all ones when ``how`` is None."""
    check_block_scaling(how)
    sizes = [int(s) for s in sizes]
    if sum(sizes) != scaled.shape[1]:
        raise ValueError(f"block sizes {sizes} must sum to the {scaled.shape[1]} features")
    weights = np.ones(scaled.shape[1])
    if how is None:
        return weights
    start = 0
    for size in sizes:
        block = scaled[:, start : start + size]
        spread = _block_spread(block, how)
        if spread > 0:  # an all-constant block is zero after scaling: nothing to weigh
            weights[start : start + size] = 1.0 / np.sqrt(spread)
        start += size
    return weights


def _block_spread(block: np.ndarray, how: str) -> float:
    """What the block's weight equalises: its count of varying features or its first eigenvalue."""
    if how == "count":
        return float(np.count_nonzero(block.std(axis=0) > 0))
    centred = block - block.mean(axis=0)
    return float(np.linalg.norm(centred, 2) ** 2 / max(len(block), 1))
