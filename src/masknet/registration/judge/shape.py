"""What a pair's template is, measured: a scan or an object, sparse or not.

``"auto"`` takes its path by two properties of the template (:mod:`masknet.registration.stages.auto`):

* **Shape.** An open surface seen from one side (a room, a 3DMatch fragment, a sensor's
  view: a *scan*) or a closed shape seen all round (a CAD model, a scanned object: an
  *object*). Measured on a seeded subset of :attr:`ShapeTable.points` points, unit-free
  and viewpoint-free, in a few milliseconds at any size (:func:`measure_shape`):

  - ``one_sided``, the largest share of the points that one direction of view sees with
    no other layer of the surface in front of them (:func:`one_sided_share`): about 1 for
    a surface seen from one side (there is a direction it is a height field along), about
    0.5-0.7 for a closed shape (every direction sees its near side and hides its far one);
  - ``inside``, the rank correlation of the point spacing with the distance from the
    centroid (:func:`seen_from_inside`): a sensor inside a room samples the walls near it
    densely and far ones sparsely, so a whole room scan, closed around its centroid, still
    reads as a scan (0.8 on the room scans); a uniformly sampled object reads about 0.

* **Size.** A template of fewer than ``consensus_below`` points is *sparse*, whatever its
  shape (:meth:`~masknet.registration.terms.options.RobustOptions.is_sparse`).

Every threshold is in :data:`SHAPE` (docs/ARCHITECTURE.md, "The routing table"). The
measure cannot tell a thin object from a sheet: at 1,024 points a table top's or a
guitar's two faces lie within the spacing, and 15-20% of ModelNet40's test shapes read
as one-sided (tables, guitars, monitors, doors, curtains). docs/RESULTS.md, "Paths chosen
by what the clouds are", has the measures of each set.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.stats import spearmanr

from masknet.geometry.clouds import median_spacing
from masknet.geometry.knn import cloud_tree
from masknet.geometry.sampling import random_subset

__all__ = [
    "SHAPE",
    "PairShape",
    "ShapeTable",
    "classify_template",
    "measure_shape",
    "one_sided_share",
    "seen_from_inside",
]


@dataclass(frozen=True)
class ShapeTable:
    """The shape measures' settings and the routing's thresholds, in one place.

    points: the seeded subset every measure sees (larger clouds cost the same).
    lines: lines of view of :func:`one_sided_share` (twice as many directions), spread
        evenly over the half sphere.
    cell_spacings: the view's grid edge, in template spacings
        (:func:`~masknet.geometry.clouds.median_spacing` of the subset).
    gap_spacings: an empty stretch along the line of view this long (in spacings) parts
        two layers; a steep wall within one cell does not.
    scan_one_sided: a template whose ``one_sided`` share is at least this is a scan ...
    scan_one_sided_large: ... or this, for a template of ``consensus_from`` points or more
        (measured before anything runs, where every template used to be a scan's): the
        280 scan views of the evaluation scans (4,096 points) read 0.78 or more, ModelNet40's
        test shapes 0.69 at the median.
    scan_inside: ... or whose ``inside`` correlation is at least this (a scene scanned
        from within it). ModelNet40's test shapes reach 0.27 at most in 99 of 100.
    partial_fit: between the sizes (measured once the fast path has not held), a scan's
        front end runs only where the fast path laid less than this share of the source
        on the template: two partial clouds (the 3DMatch pair thinned to 1,000-1,500
        points: 0.29-0.34), not a part of a thin object near its pose (noisy ModelNet40
        pairs the front end turned 4 degrees off: 0.87 and 0.96).
    """

    points: int = 1024
    lines: int = 32
    cell_spacings: float = 1.4
    gap_spacings: float = 1.4
    scan_one_sided: float = 0.80
    scan_one_sided_large: float = 0.75
    scan_inside: float = 0.35
    partial_fit: float = 0.8


SHAPE = ShapeTable()


class PairShape(NamedTuple):
    """A template's class: ``kind`` ``"scan"`` or ``"object"`` (:data:`SHAPE`'s
    thresholds), and the measures it came from."""

    kind: str
    one_sided: float
    inside: float


def _lines(count: int) -> np.ndarray:
    """(count, 3) unit vectors spread evenly over the upper half sphere (a Fibonacci
    lattice: heights evenly spaced, each turned by the golden angle from the last)."""
    height = 1 - (np.arange(count) + 0.5) / count
    turn = np.pi * (1 + 5**0.5) * np.arange(count)
    ring = np.sqrt(1 - height**2)
    return np.stack([np.cos(turn) * ring, np.sin(turn) * ring, height], 1)


def _subset(points: np.ndarray, table: ShapeTable, seed: int) -> np.ndarray:
    """The seeded subset of ``table.points`` every measure sees, float64 (P, 3)."""
    return np.asarray(random_subset(np.asarray(points, np.float64), table.points, seed))


def one_sided_share(
    points: np.ndarray, table: ShapeTable = SHAPE, seed: int = 0, tree: object | None = None
) -> float:
    """The largest share, over ``2 * table.lines`` directions of view, of the points of
    ``points`` (P, 3) (a seeded subset of ``table.points``) that the direction sees with no
    other layer in front: the subset projected along the direction onto a grid of
    ``cell_spacings`` spacings, and a point hidden where a point of its cell lies over
    ``gap_spacings`` spacings nearer with an empty stretch that long between them. In [0, 1];
    1 for a height field along some direction (a sensor's view), 0.55-0.7 for a sphere, a
    box or a ModelNet40 shape's median. ``tree``: a tree of the subset, built here when None."""
    cloud = _subset(points, table, seed)
    spacing = median_spacing(cloud, tree) if len(cloud) >= 4 else 0.0
    cloud = cloud - cloud.mean(0)
    if not spacing > 0:
        return 1.0
    views = _lines(table.lines)
    across = np.cross(views, [0.36, 0.48, 0.8])
    across /= np.linalg.norm(across, axis=1, keepdims=True)
    up = np.cross(views, across)
    cells = [np.floor(cloud @ axes.T / (table.cell_spacings * spacing)) for axes in (across, up)]
    cells = [(c - c.min(0)).astype(np.int64) for c in cells]
    rows = cells[1].max() + 1
    per_line = rows * (cells[0].max() + 1)
    key = (cells[0] * rows + cells[1] + np.arange(len(views)) * per_line).T.ravel()
    depth = (cloud @ views.T).T.ravel()  # (lines * P,), line by line
    # One sort: by cell, and by depth within a cell (the depth scaled into [0, 0.5]).
    span = max(float(np.ptp(depth)), 1e-300)
    order = np.argsort(key + 0.5 * (depth - depth.min()) / span, kind="stable")
    k, z = key[order], depth[order]
    same = k[1:] == k[:-1]
    gap = same & (np.diff(z) > table.gap_spacings * spacing)  # between sorted i and i + 1
    first = np.r_[0, np.flatnonzero(~same) + 1]  # each cell's first and end positions
    length = np.diff(np.r_[first, len(k)])
    before = np.r_[0, np.cumsum(gap)]  # gaps below position i within the whole order
    # Seen from below (-direction) a point is hidden by a gap below it in its cell; from
    # above, by one above it.
    from_below = before - np.repeat(before[first], length) > 0
    from_above = np.repeat(before[first + length - 1], length) - before > 0
    view_of = k // per_line
    hidden = [
        np.bincount(view_of, weights=h, minlength=len(views)) for h in (from_below, from_above)
    ]
    return 1.0 - float(min(h.min() for h in hidden)) / len(cloud)


def seen_from_inside(
    points: np.ndarray, table: ShapeTable = SHAPE, seed: int = 0, tree: object | None = None
) -> float:
    """The rank (Spearman) correlation, over a seeded subset of ``table.points`` of
    ``points`` (P, 3), between each point's nearest-neighbour distance and its distance
    from the centroid: near 0 for an evenly sampled shape, 0.3-0.9 for a scene scanned
    from within it (a sensor's samples thin out with distance). ``tree``: a tree of the
    subset, built here when None."""
    cloud = _subset(points, table, seed)
    if len(cloud) < 4:
        return 0.0
    tree = cloud_tree(cloud) if tree is None else tree
    near = tree.query(cloud, k=2)[0][:, 1]
    far = np.linalg.norm(cloud - cloud.mean(0), axis=1)
    if np.ptp(near) == 0 or np.ptp(far) == 0:  # a constant has no rank correlation
        return 0.0
    # Ties share their mean rank (mutual nearest neighbours have equal distances).
    return float(spearmanr(near, far).statistic)


def measure_shape(points: np.ndarray, table: ShapeTable = SHAPE) -> tuple[float, float]:
    """(one_sided, inside) of a cloud (P, 3): :func:`one_sided_share` and
    :func:`seen_from_inside`, on one subset and one tree of it."""
    cloud = _subset(points, table, 0)
    tree = cloud_tree(cloud) if len(cloud) >= 4 else None
    return one_sided_share(cloud, table, tree=tree), seen_from_inside(cloud, table, tree=tree)


def classify_template(
    template: np.ndarray, table: ShapeTable = SHAPE, large: bool = False
) -> PairShape:
    """The class of a pair by its template (N, 3): a scan where it is one-sided or seen
    from inside (``table``'s thresholds; ``large``: a template of ``consensus_from``
    points or more, ``scan_one_sided_large``), else an object."""
    one_sided, inside = measure_shape(template, table)
    level = table.scan_one_sided_large if large else table.scan_one_sided
    scan = one_sided >= level or inside >= table.scan_inside
    return PairShape("scan" if scan else "object", one_sided, inside)
