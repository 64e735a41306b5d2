"""Trimmed fits: how well the best share of one cloud's points lies on another, a score
that parts one cloud does not see (or clutter) cannot spoil. The scene search ranks its
placements with them."""

from __future__ import annotations

import numpy as np

from masknet.geometry.knn import cloud_tree

__all__ = ["trimmed_fit", "trimmed_mean", "trimmed_order"]


def trimmed_order(
    d2: np.ndarray, trim: float, valid: np.ndarray, min_keep: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """Each row of (B, P) squared distances sorted, invalid entries (``valid`` (B, P)
    False) last as inf, and how many of each row the ``trim`` fraction of its valid
    entries keeps (B,), at least ``min_keep``."""
    ordered = np.sort(np.where(valid, d2, np.inf), axis=1)
    keep = np.maximum(min_keep, np.round(trim * valid.sum(1))).astype(np.int64)
    return ordered, keep


def trimmed_mean(d2: np.ndarray, trim: float, valid: np.ndarray | None = None) -> np.ndarray:
    """Mean of the smallest ``trim`` fraction of each row of (B, P) squared distances: (B,).

    ``valid`` (B, P) bool limits each row to its valid entries (the fraction is of those);
    a row without any is inf.
    """
    if valid is None:
        keep = max(1, int(round(trim * d2.shape[1])))
        return np.sort(d2, axis=1)[:, :keep].mean(1)
    ordered, keep = trimmed_order(d2, trim, valid)
    sums = np.cumsum(np.where(np.isfinite(ordered), ordered, 0.0), axis=1)
    means = sums[np.arange(len(d2)), keep - 1] / keep
    return np.where(valid.any(1), means, np.inf)


def trimmed_fit(query: np.ndarray, reference: np.ndarray, trim: float) -> np.ndarray:
    """Mean squared distance of the best ``trim`` fraction of query points (B, P, 3) to
    their nearest reference point (B, R, 3): (B,)."""
    d2 = np.stack(
        [
            cloud_tree(r).query(q, k=1, sqr_dists=True)[0]
            for q, r in zip(query, reference, strict=True)
        ]
    )
    return trimmed_mean(d2, trim)
