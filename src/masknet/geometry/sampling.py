"""Even subsets of large real clouds: farthest point sampling for the network's input,
and a voxel grid for the fit and ICP of registration.

Farthest point sampling (FPS) spreads the kept points evenly over the surface,
like the area-uniform samples the networks were trained on, whatever the
scanner's density. Its covering radius (the largest distance from any point to
the nearest kept one) measures the spacing reached, which lets a partial source
be sampled at the same spacing as its template, so that the number of source
points still says how much of the template it covers.

A grid subset (:func:`grid_subset`) keeps one point per occupied voxel: as even as FPS
where it matters (a scanner's points per square metre fall with the square of the
range, and a random subset keeps that bias) at a cost that stays linear in the points.
"""

from __future__ import annotations

import time
from functools import cached_property
from typing import NamedTuple

import fpsample
import numpy as np

from masknet.errors import MaskNetError
from masknet.geometry.knn import cloud_tree

__all__ = [
    "NetworkClouds",
    "FPSResult",
    "farthest_point_sample",
    "first_in_cells",
    "fit_to_network",
    "grid_subset",
    "nearest_sample",
    "random_subset",
    "spread_mask",
]

# Above this many points, FPS and the grid run on a seeded uniform random subset of this
# size first: the result is the same in distribution and the cost stays bounded.
PRESAMPLE = 100_000


# FPS of a cloud larger than this many times the points it keeps runs on a seeded random
# subset of that size: FPS costs the cloud's size times the points kept (76 ms for 1,024 of
# the carton's 12,575 points, 15-19 ms from 4,096), and what it keeps of a subset four
# times as large covers the cloud about as well (the carton's pose stayed the same).
FPS_POOL = 4


def _pool_size(max_points: int) -> int:
    """The random pool FPS runs on for ``max_points`` kept points, at most."""
    return min(PRESAMPLE, FPS_POOL * max_points)


class FPSResult(NamedTuple):
    """indices: (K,) int64 into the input cloud, in sampling order.
    radius: the covering radius after the last kept point, in the cloud's units."""

    indices: np.ndarray
    radius: float


def farthest_point_sample(
    points: np.ndarray,
    max_points: int,
    min_spacing: float = 0.0,
    seed: int = 0,
    pool: int | None = None,
) -> FPSResult:
    """Keep at most ``max_points`` points of ``points`` (N, 3) by farthest point sampling.

    Sampling starts at point 0 (the pool's first point, where one is drawn: below) and
    stops early once the covering radius is at most ``min_spacing``: every input point
    (every pool point) then lies within ``min_spacing`` of a kept one.
    With N <= max_points and ``min_spacing=0`` every point is kept (in input order,
    radius 0). The sampling itself is exact FPS in compiled code (``fpsample``), over the
    whole cloud or, for clouds of over ``FPS_POOL`` times ``max_points`` points, over a
    seeded random subset of that many (``pool`` sets the size; at most ``PRESAMPLE``),
    and the covering radius and ``min_spacing`` are the subset's: a maximum over fewer
    points, below the whole cloud's. Compare radii of subsets equally dense: as
    :func:`fit_to_network` takes them.

    Returns:
        FPSResult(indices (K,), radius); K <= min(N, max_points).
    """
    n = len(points)
    if n <= max_points and min_spacing <= 0:
        return FPSResult(np.arange(n), 0.0)
    size = _pool_size(max_points) if pool is None else min(PRESAMPLE, max(pool, 1))
    kept = np.arange(n)
    if n > size:
        kept = np.sort(np.random.default_rng(seed).choice(n, size, replace=False))
    cloud = np.ascontiguousarray(points[kept], dtype=np.float32)
    k = min(max_points, len(kept))
    order = np.asarray(fpsample.fps_sampling(cloud, k, start_idx=0), dtype=np.int64)
    if min_spacing > 0:
        stop = _first_gap_at_most(cloud[order], min_spacing)
        if stop is not None:
            return FPSResult(kept[order[: stop[0]]], stop[1])
    radius = float(
        cloud_tree(cloud[order].astype(np.float64)).query(cloud.astype(np.float64), k=1)[0].max()
    )
    return FPSResult(kept[order], radius)


def _first_gap_at_most(chosen: np.ndarray, spacing: float) -> tuple[int, float] | None:
    """In FPS order (``chosen`` (K, 3)), the covering radius of the first j points is the
    distance from point j (0-based) to them, its gap, and gaps never grow (to float32's
    rounding, in which the sampling runs: on real scans they rose by at most 6e-8 of
    themselves): the first j >= 1 whose gap is at most ``spacing``, and that gap, found by
    bisection (a tree of the first j points per probe: 0.2 ms on 1,024 points, against
    48 ms for every gap); None where no gap is that small."""
    from masknet.geometry.knn import cloud_tree

    points = chosen.astype(np.float64)

    def gap(j: int) -> float:
        return float(cloud_tree(points[:j]).query(points[j : j + 1], k=1)[0][0])

    low, high = 1, len(points) - 1  # the answer, if any, lies in [low, high]
    if high < low or gap(high) > spacing:
        return None
    while low < high:
        middle = (low + high) // 2
        if gap(middle) <= spacing:
            high = middle
        else:
            low = middle + 1
    return low, gap(low)


def first_in_cells(points: np.ndarray, edge: float, origin: np.ndarray | None = None) -> np.ndarray:
    """Indices (K,) int64 of the first point (in input order) of ``points`` (P, 3) in each
    occupied cell of a cubic grid of edge ``edge`` with a corner at ``origin`` (3,) (None:
    the points' lower corner), in the cells' order (one int64 key per cell: a 1-D sort,
    not a sort of rows)."""
    if not len(points):
        return np.empty(0, np.int64)
    cells = np.floor((points - (points.min(0) if origin is None else origin)) / edge)
    cells = cells.astype(np.int64)
    cells -= cells.min(0)
    try:  # raises where the grid holds more cells than an int64 counts
        keys = np.ravel_multi_index(cells.T, cells.max(0) + 1)
    except ValueError:
        return np.unique(cells, axis=0, return_index=True)[1]
    return np.unique(keys, return_index=True)[1]


def grid_subset(points: np.ndarray, count: int, seed: int = 0) -> np.ndarray:
    """Indices (K,) int64 of at most ``count`` of ``points`` (P, 3), one per occupied cell
    of a cubic grid whose edge leaves about ``count`` cells (K within 10% below ``count``
    on surfaces; a seeded random choice within each cell and among the cells when the grid
    leaves more; the cells are filled from a random ``PRESAMPLE`` of larger clouds). Every
    index, in order, when P <= count.

    Space, not the sensor, sets the density: a random subset of a laser scan weighs the
    floor at the scanner's feet by hundreds over a wall a few metres away, and a fit on it
    prefers any pose that keeps the scanner in place."""
    n = len(points)
    if n <= count:
        return np.arange(n)
    rng = np.random.default_rng(seed)
    # The first point of a cell in this order represents it; above PRESAMPLE points, a
    # random PRESAMPLE of them are the candidates, which bounds the cost as for FPS.
    order = rng.permutation(n)[:PRESAMPLE]
    shuffled = points[order]
    low = shuffled.min(0)
    extent = float((shuffled.max(0) - low).max()) or 1.0
    edge = extent / np.sqrt(count)  # a surface fills about (extent / edge)^2 cells
    for _ in range(8):
        first = first_in_cells(shuffled, edge)
        if 0.9 * count <= len(first) <= count:
            break
        # Cells scale with the inverse square of the edge on a surface; a little over
        # the ratio so that a count just above converges from below.
        edge *= np.sqrt(len(first) / count) * (1.02 if len(first) > count else 1.0)
    if len(first) > count:
        first = rng.choice(first, count, replace=False)
    return np.sort(order[first])


def spread_mask(template: np.ndarray, sampled: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Give every template point (N, 3) the mask label (K,) of its nearest sampled point
    (indices (K,)); returns (N,)."""
    return mask[nearest_sample(template, sampled)]


def spread_labels(points: np.ndarray, labelled: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """The one label spreader: every point of ``points`` (P, 3) takes the label of its
    nearest point of ``labelled`` (K, 3), whose labels are ``labels`` (K, ...); returns
    (P, ...)."""
    return labels[nearest_of(points, labelled)]


def nearest_of(points: np.ndarray, among: np.ndarray) -> np.ndarray:
    """(P,) int64: for every point of ``points`` (P, 3), the row of its nearest point in
    ``among`` (K, 3)."""
    _, nearest = cloud_tree(among).query(points, k=1)
    return nearest.astype(np.int64)


def nearest_sample(points: np.ndarray, sampled: np.ndarray) -> np.ndarray:
    """For every point of ``points`` (N, 3), the position (N,) int64 in ``sampled`` (indices
    (K,)) of its nearest sampled point: ``labels[nearest_sample(...)]`` spreads labels (K,)
    of the samples to every point, for many labellings of one sample."""
    return nearest_of(points, points[sampled])


def fit_to_network(
    template: np.ndarray, source: np.ndarray, single: bool, max_points: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Subsample a single large pair, template (1, N, 3) and source (1, M, 3), to at most
    ``max_points`` each; returns (template, source, template indices, source indices),
    the indices None where nothing was sampled."""
    n, m = template.shape[1], source.shape[1]
    if n <= max_points and m <= max_points:
        return template, source, None, None
    if not single:
        raise MaskNetError(
            f"batched clouds must have at most max_points={max_points} points "
            f"(got template {n}, source {m}); pass large clouds one pair at a time"
        )
    from masknet.geometry.prepared_template import template_view

    kept = template_view(
        template,
        ("farthest points", max_points),
        lambda: farthest_point_sample(template[0], max_points),
    )
    # The source at the template's spacing, so its size still reflects the overlap
    # (top-k selection uses it): from a pool as dense as the template's, whose radius
    # that spacing is.
    share = min(1.0, _pool_size(max_points) / n)
    src_idx = farthest_point_sample(
        source[0], max_points, min_spacing=kept.radius, pool=int(np.ceil(share * m))
    ).indices
    sampled = template_view(
        template, ("network sample", max_points), lambda: template[:, kept.indices], True
    )
    return sampled, source[:, src_idx], kept.indices, src_idx


class NetworkClouds:
    """A pair at the networks' size, sampled on first use by :func:`fit_to_network`: a
    pipeline that ends before any network runs (a scan registered by its consensus
    front end) pays nothing for it. template, source: (B, N, 3) and (B, M, 3);
    ``times["sample"]`` gets the seconds the sampling took.

    Example::

        nets = NetworkClouds(template, source, single=True, max_points=1024, times={})
        nets.template.shape  # (1, 1024, 3), sampled now
    """

    def __init__(
        self,
        template: np.ndarray,
        source: np.ndarray,
        single: bool,
        max_points: int,
        times: dict[str, float] | None = None,
    ) -> None:
        self._clouds = template, source, single, max_points
        self._times = {} if times is None else times

    @classmethod
    def given(cls, template: np.ndarray, source: np.ndarray) -> NetworkClouds:
        """Clouds already at the networks' size: (B, n, 3) and (B, m, 3), kept as they are."""
        return cls(
            template, source, template.shape[0] == 1, max(template.shape[1], source.shape[1])
        )

    @cached_property
    def sampled(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
        """(template, source, template indices, source indices), the indices None where
        nothing was sampled."""
        tic = time.perf_counter()
        out = fit_to_network(*self._clouds)
        self._times["sample"] = self._times.get("sample", 0.0) + time.perf_counter() - tic
        return out

    def sizes(self) -> tuple[int, int]:
        """(template, source) points the networks saw; the clouds' own sizes where no
        network asked for them."""
        clouds = self.sampled if "sampled" in self.__dict__ else self._clouds
        return clouds[0].shape[1], clouds[1].shape[1]

    @property
    def template(self) -> np.ndarray:
        return self.sampled[0]

    @property
    def source(self) -> np.ndarray:
        return self.sampled[1]


def random_subset(points: np.ndarray, count: int, seed: int = 0) -> np.ndarray:
    """At most ``count`` of ``points`` (P, 3), a seeded random subset without repeats."""
    if len(points) <= count:
        return points
    return points[np.random.default_rng(seed).choice(len(points), count, replace=False)]
