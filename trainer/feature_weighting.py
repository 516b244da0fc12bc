"""How much each standardised feature weighs in the SVM's distance (FeatureSVC ``feature_weighting``).

After one StandardScaler every non-constant feature has unit variance, so a family's share of the
squared RBF distance grows with how many features it has and how redundant they are, and a quantity
two families both compute counts twice. Fixed rules (nothing searched), from the training cases only:

- ``"block_count"``: divide each standardised family block by sqrt(its non-constant features), so
  every block's total variance is 1 (constant features are zero after scaling and count for nothing);
- ``"block_mfa"``: divide each standardised block by sqrt(the largest eigenvalue of its covariance), as
  Multiple Factor Analysis does (Escofier & Pages 1994; Abdi, Williams & Valentin 2013): every
  block's first principal direction then has unit variance, so a family of many features that all
  say the same (e.g. several pressure levels) does not outweigh a family of a few independent ones;
- ``"distinct"``: features that are the same quantity on the training cases (|correlation| >= 1 - 1e-6,
  e.g. the hand family's pad maximum and the stats family's peak) share one feature's weight.

The weights are folded into the scaler (``scale_ / weight``), so the exported graph, its float64
reference and the float32 bounds of ``handover verify`` stay the scaler's own.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["FEATURE_WEIGHTINGS", "check_feature_weighting", "feature_weights"]

FEATURE_WEIGHTINGS = (None, "block_count", "block_mfa", "distinct")


def check_feature_weighting(how) -> None:
    """One clear error for an unknown ``feature_weighting``."""
    if how not in FEATURE_WEIGHTINGS:
        raise ValueError(f"feature_weighting must be one of {FEATURE_WEIGHTINGS}, got {how!r}")


def feature_weights(scaled: np.ndarray, sizes: Sequence[int], how: str | None) -> np.ndarray:
    """One weight per feature (``(F,)``) for the standardised training features ``scaled`` ``(n, F)``
    whose blocks have ``sizes`` features each, in order; all ones when ``how`` is None."""
    check_feature_weighting(how)
    sizes = [int(s) for s in sizes]
    if sum(sizes) != scaled.shape[1]:
        raise ValueError(f"block sizes {sizes} must sum to the {scaled.shape[1]} features")
    weights = np.ones(scaled.shape[1])
    if how is None:
        return weights
    if how == "distinct":
        return distinct_weights(scaled)
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
    if how == "block_count":
        return float(np.count_nonzero(block.std(axis=0) > 0))
    centred = block - block.mean(axis=0)
    return float(np.linalg.norm(centred, 2) ** 2 / max(len(block), 1))


DUPLICATE_CORRELATION = 1.0 - 1e-6
"""Two features with |correlation| at least this on the training cases are the same quantity (e.g.
the hand family's pad mean and the stats family's mean pressure: one is the other / fullscale)."""


def distinct_weights(scaled: np.ndarray) -> np.ndarray:
    """``(F,)``: 1/sqrt(k) for each feature of a group of k duplicates (features linked by
    |correlation| >= ``DUPLICATE_CORRELATION``, transitively), 1 for the rest: a quantity that two
    families both compute counts once in the squared distance, not k times."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    std = scaled.std(axis=0)
    varying = np.flatnonzero(std > 0)
    weights = np.ones(scaled.shape[1])
    if len(varying) < 2:
        return weights
    z = (scaled[:, varying] - scaled[:, varying].mean(axis=0)) / std[varying]
    rows, cols = [], []
    for start in range(0, len(varying), _CHUNK):  # correlations a chunk of columns at a time: F x F may not fit
        corr = z[:, start : start + _CHUNK].T @ z / len(z)
        i, j = np.nonzero(np.abs(corr) >= DUPLICATE_CORRELATION)
        rows.append(i + start)
        cols.append(j)
    i, j = np.concatenate(rows), np.concatenate(cols)
    same = coo_matrix((np.ones(len(i)), (i, j)), shape=(len(varying),) * 2)
    _, group = connected_components(same, directed=False)
    weights[varying] = 1.0 / np.sqrt(np.bincount(group)[group])
    return weights


_CHUNK = 512
