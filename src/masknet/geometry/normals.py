"""Surface normals by principal component analysis of each point's neighbourhood."""

from __future__ import annotations

import torch
from torch import Tensor

from masknet.geometry.knn import knn_points

__all__ = ["estimate_normals"]


def estimate_normals(points: Tensor, k: int = 16) -> tuple[Tensor, Tensor]:
    """Unit normals (B, N, 3) of clouds (B, N, 3), and the neighbour indices used (B, N, k).

    The normal of point i is the eigenvector of the smallest eigenvalue of the
    covariance of its k nearest points (itself included). Its sign is arbitrary:
    users of these normals must not depend on it (RPM-Net's features here use
    absolute cosines). Computed without gradients.
    """
    k = min(k, points.shape[1])
    with torch.no_grad():
        idx = knn_points(points, points, k).idx
        b, n, _ = points.shape
        flat = idx.reshape(b, -1, 1).expand(-1, -1, 3)
        neighbours = torch.gather(points, 1, flat).reshape(b, n, k, 3).double()
        centred = neighbours - neighbours.mean(2, keepdim=True)
        cov = centred.transpose(-1, -2) @ centred  # (B, N, 3, 3)
        _, vectors = torch.linalg.eigh(cov)  # ascending eigenvalues
        return vectors[..., 0].to(points.dtype), idx
