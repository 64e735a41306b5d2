"""Mask quality metrics, per pair, with the real false negatives.

The official MaskNet code computed recall with FN set equal to FP; here
FN counts the true inliers that the prediction missed.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

__all__ = ["outlier_removal_metrics", "MaskMetrics", "mask_metrics"]


class MaskMetrics(NamedTuple):
    """Per-pair scores, each a (B,) float tensor in [0, 1].

    A ratio whose denominator is zero (e.g. precision of an empty prediction) is 0.
    """

    precision: Tensor
    recall: Tensor
    f1: Tensor
    iou: Tensor

    def mean(self) -> dict[str, float]:
        return {name: float(value.float().mean()) for name, value in self._asdict().items()}


def _ratio(num: Tensor, den: Tensor) -> Tensor:
    return torch.where(den > 0, num / den.clamp_min(1), torch.zeros_like(num))


def mask_metrics(predicted: Tensor, truth: Tensor) -> MaskMetrics:
    """Precision, recall, F1 and IoU of Boolean masks (B, N) against ground truth (B, N)."""
    predicted, truth = predicted.bool(), truth.bool()
    tp = (predicted & truth).sum(-1).float()
    fp = (predicted & ~truth).sum(-1).float()
    fn = (~predicted & truth).sum(-1).float()
    return MaskMetrics(
        precision=_ratio(tp, tp + fp),
        recall=_ratio(tp, tp + fn),
        f1=_ratio(2 * tp, 2 * tp + fp + fn),
        iou=_ratio(tp, tp + fp + fn),
    )


def outlier_removal_metrics(kept: np.ndarray, real: np.ndarray) -> dict[str, float]:
    """How well a filter removed outliers, pooled over clouds.

    Args:
        kept: (P, K) or (K,) bool, the points the filter kept.
        real: same shape, True for real points, False for the added outliers.

    Returns:
        ``outlier_precision`` (removed points that were outliers), ``outlier_recall``
        (outliers removed) and ``inliers_kept`` (real points kept).
    """
    removed, outlier = ~np.asarray(kept, bool), ~np.asarray(real, bool)
    hit = (removed & outlier).sum()
    return {
        "outlier_precision": float(hit / max(removed.sum(), 1)),
        "outlier_recall": float(hit / max(outlier.sum(), 1)),
        "inliers_kept": float((~removed & ~outlier).sum() / max((~outlier).sum(), 1)),
    }
