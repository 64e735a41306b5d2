"""Farthest point sampling: bring a large real cloud to the network's size.

Farthest point sampling (FPS) spreads the kept points evenly over the surface,
like the area-uniform samples the networks were trained on, whatever the
scanner's density. Its covering radius (the largest distance from any point to
the nearest kept one) measures the spacing reached, which lets a partial source
be sampled at the same spacing as its template, so that the number of source
points still says how much of the template it covers.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch

__all__ = ["FPSResult", "farthest_point_sample"]

# Above this many points, FPS runs on a seeded uniform random subset of this size
# first: the result is the same in distribution and the cost stays bounded.
PRESAMPLE = 100_000


class FPSResult(NamedTuple):
    """indices: (K,) int64 into the input cloud, in sampling order.
    radius: the covering radius after the last kept point, in the cloud's units."""

    indices: np.ndarray
    radius: float


def farthest_point_sample(
    points: np.ndarray, max_points: int, min_spacing: float = 0.0, seed: int = 0
) -> FPSResult:
    """Keep at most ``max_points`` points of ``points`` (N, 3) by farthest point sampling.

    Sampling stops early once the covering radius is at most ``min_spacing``: every
    input point then lies within ``min_spacing`` of a kept one. With N <= max_points
    and ``min_spacing=0`` every point is kept (in input order, radius 0).

    Returns:
        FPSResult(indices (K,), radius); K <= min(N, max_points).
    """
    n = len(points)
    if n <= max_points and min_spacing <= 0:
        return FPSResult(np.arange(n), 0.0)
    pool = np.arange(n)
    if n > PRESAMPLE:
        pool = np.sort(np.random.default_rng(seed).choice(n, PRESAMPLE, replace=False))
    cloud = torch.from_numpy(np.ascontiguousarray(points[pool], dtype=np.float32))
    nearest = torch.full((len(pool),), float("inf"), dtype=torch.float32)
    chosen = [0]
    radius = 0.0
    for _ in range(min(max_points, len(pool))):
        d2 = (cloud - cloud[chosen[-1]]).square().sum(1)
        torch.minimum(nearest, d2, out=nearest)
        far = int(nearest.argmax())
        radius = float(nearest[far].sqrt())
        if radius <= min_spacing or len(chosen) == max_points:
            break
        chosen.append(far)
    return FPSResult(pool[np.asarray(chosen)], radius)
