"""Closed-form rigid alignment of corresponding points (weighted Kabsch / Umeyama, no scale).

The result follows the project's transform convention (:mod:`masknet.geometry.se3`):
``R``, ``t`` map source points onto their targets, ``target ~= source @ R.T + t``.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

__all__ = [
    "centroid",
    "rigid_align",
    "rigid_transforms_numpy",
]


def centroid(points: Tensor, valid: Tensor | None = None) -> Tensor:
    """Mean of each cloud's points, only the ``valid`` ones if given: (B, N, 3) -> (B, 3).

    ``valid`` is (B, N) bool; a cloud with no valid point gets the origin.
    """
    if valid is None:
        return points.mean(1)
    w = valid.to(points.dtype)[..., None]
    return (points * w).sum(1) / w.sum(1).clamp_min(1)


def rigid_align(
    source: Tensor, target: Tensor, weights: Tensor | None = None
) -> tuple[Tensor, Tensor]:
    """The rotation and translation that best map ``source`` onto ``target``.

    Minimises ``sum_i w_i ||R s_i + t - y_i||^2`` over rotations R (det +1, never a
    reflection: the smallest singular direction is flipped when needed) and
    translations t. The solve runs in float64 whatever the input dtype.

    Args:
        source: (B, P, 3) points s_i.
        target: (B, P, 3) corresponding points y_i.
        weights: (B, P) non-negative weights, or None for all ones. A batch element
            whose weights sum to zero has nothing to align and gets the identity.

    Returns:
        R (B, 3, 3) and t (B, 3), in the dtype of ``source``.
    """
    if source.dim() != 3 or source.shape[-1] != 3 or source.shape != target.shape:
        raise ValueError(
            f"expected source and target of the same shape (B,P,3), got "
            f"{tuple(source.shape)} and {tuple(target.shape)}"
        )
    if weights is not None and weights.shape != source.shape[:2]:
        raise ValueError(
            f"expected weights of shape {tuple(source.shape[:2])}, got {tuple(weights.shape)}"
        )
    s, y = source.double(), target.double()
    w = torch.ones(s.shape[:2], dtype=s.dtype, device=s.device) if weights is None else weights
    w = w.to(s)
    total = w.sum(1)  # (B,)
    has_weight = total > 0
    wn = w / torch.where(has_weight, total, torch.ones_like(total))[:, None]  # sums to 1 or 0
    s_mean = (wn[..., None] * s).sum(1)  # (B, 3)
    y_mean = (wn[..., None] * y).sum(1)
    # Weighted cross-covariance H = sum_i w_i (s_i - s_mean)(y_i - y_mean)^T, (B, 3, 3).
    cov = (s - s_mean[:, None]).transpose(1, 2) @ (wn[..., None] * (y - y_mean[:, None]))
    u, _, vh = torch.linalg.svd(cov)
    v = vh.transpose(1, 2)
    # R = V diag(1, 1, d) U^T with d = det(V U^T) = +-1 keeps det(R) = +1.
    d = torch.linalg.det(v @ u.transpose(1, 2)).sign()
    d = torch.where(d == 0, torch.ones_like(d), d)
    fix = torch.ones(s.shape[0], 3, dtype=s.dtype, device=s.device)
    fix[:, 2] = d
    rot = (v * fix[:, None, :]) @ u.transpose(1, 2)
    eye = torch.eye(3, dtype=s.dtype, device=s.device).expand_as(rot)
    rot = torch.where(has_weight[:, None, None], rot, eye)
    trans = y_mean - (rot @ s_mean[..., None])[..., 0]
    return rot.to(source.dtype), trans.to(source.dtype)


def rigid_transforms_numpy(
    source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None
) -> np.ndarray:
    """:func:`rigid_align` for many small problems at once in numpy float64: transforms
    (B, 4, 4) taking source (B, K, 3) onto target (B, K, 3), with optional (B, K)
    weights (rows of weight 0 take no part; a problem without weight gets the identity).
    For RANSAC's minimal samples and ICP from many starts, where one batched 3x3 SVD
    replaces a Python loop."""
    if weights is None:  # the plain means: no weight arrays for ICP's many single solves
        total = np.full(len(source), float(source.shape[1]))
        s_mean = source.mean(1, keepdims=True)
        y_mean = target.mean(1, keepdims=True)
        cov = (source - s_mean).transpose(0, 2, 1) @ (target - y_mean)
    else:
        w = weights
        total = w.sum(1)
        norm = np.maximum(total, 1e-300)[:, None, None]
        s_mean = (w[..., None] * source).sum(1, keepdims=True) / norm
        y_mean = (w[..., None] * target).sum(1, keepdims=True) / norm
        cov = ((source - s_mean) * w[..., None]).transpose(0, 2, 1) @ (target - y_mean)
    u, _, vh = np.linalg.svd(cov)
    rot = vh.transpose(0, 2, 1) @ u.transpose(0, 2, 1)
    # R = V diag(1, 1, d) U^T with d = det(V U^T): a reflection flips V's last column.
    flip = np.linalg.det(rot) < 0
    if flip.any():
        v = vh.transpose(0, 2, 1)[flip]
        v[:, :, 2] *= -1
        rot[flip] = v @ u[flip].transpose(0, 2, 1)
    rot[total <= 0] = np.eye(3)
    out = np.zeros((len(cov), 4, 4))
    out[:, :3, :3] = rot
    out[:, :3, 3] = y_mean[:, 0] - (rot @ s_mean.transpose(0, 2, 1))[..., 0]
    out[:, 3, 3] = 1.0
    return out
