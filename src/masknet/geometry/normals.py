"""Surface normals by principal component analysis of each point's neighbourhood."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import Tensor

from masknet.geometry.knn import knn_points

__all__ = ["estimate_normals", "least_spread_axis", "normals_at", "plane_offsets"]


def estimate_normals(points: Tensor | np.ndarray, k: int = 16, tree: Any | None = None) -> tuple:
    """Unit normals (B, N, 3) of clouds (B, N, 3), and the neighbour indices used (B, N, k).

    The normal of point i is the eigenvector of the smallest eigenvalue of the
    covariance of its k nearest points (itself included). Its sign is arbitrary:
    users of these normals must not depend on it (RPM-Net's features here use
    absolute cosines, point-to-plane ICP squares them). Computed without gradients.

    A numpy cloud (N, 3) gives numpy (N, 3) float64 and (N, k), its neighbours from a
    KD-tree (``tree``: one from :func:`masknet.geometry.knn.cloud_tree` of ``points``, built
    here when None), so that large clouds need no (N, N) distances.
    """
    if isinstance(points, np.ndarray):
        from masknet.geometry.knn import cloud_tree

        points = np.asarray(points, np.float64)
        k = min(k, len(points))
        tree = cloud_tree(points) if tree is None else tree
        idx = tree.query(points, k=k)[1].astype(np.int64).reshape(len(points), k)
        return _pca_normals(points[idx])[0], idx
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


def normals_at(cloud: np.ndarray, at: np.ndarray, tree: Any, k: int = 16) -> np.ndarray:
    """Unit normals (A, 3), float64, of ``cloud`` (N, 3) at its points ``at`` (A,) indices:
    the covariance's smallest eigenvector over each point's ``k`` nearest (itself
    included), as :func:`estimate_normals` takes them, for a few points of a large cloud.
    ``tree``: :func:`masknet.geometry.knn.cloud_tree` of ``cloud``. Signs are arbitrary."""
    k = min(k, len(cloud))
    idx = tree.query(cloud[at], k=k)[1].astype(np.int64).reshape(len(at), k)
    return _pca_normals(np.asarray(cloud, np.float64)[idx])[0]


def plane_offsets(
    points: np.ndarray, neighbours: np.ndarray, cloud: np.ndarray | None = None
) -> np.ndarray:
    """(N,) the distance of each point of ``points`` (N, 3) from the least-squares plane of
    its neighbours, ``neighbours`` (N, k) indices into ``cloud`` (K, 3; ``points`` itself
    when None), k >= 3, the point itself not among them (it would tilt the plane towards
    itself); in the points' units. A point on a surface lies near that plane; a stray point
    beside the surface, whose neighbours are surface points, does not."""
    cloud = points if cloud is None else cloud
    normals, centres = _pca_normals(cloud[neighbours])
    return np.abs(np.einsum("ni,ni->n", normals, points - centres))


def _pca_normals(neighbours: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (N, 3) and centres (N, 3) of neighbourhoods (N, k, 3), float64: the
    eigenvector of each covariance's smallest eigenvalue, and the mean."""
    centres = neighbours.mean(1)
    centred = neighbours - centres[:, None]
    _, vectors = np.linalg.eigh(centred.transpose(0, 2, 1) @ centred)
    return vectors[..., 0], centres


def least_spread_axis(points: np.ndarray) -> np.ndarray:
    """(3,) unit direction (sign arbitrary) along which ``points`` (P, 3) spread least: the
    normal of their least-squares plane, through their centroid."""
    return np.linalg.eigh(np.cov((points - points.mean(0)).T))[1][:, 0]
