"""A pair prepared once for the fit and ICP of ``auto`` and ``robust``, and the fit itself.

As small_gicp prepares a cloud (down-sample, KD-tree) and then aligns against it,
:func:`prepare_pair` brings a pair to what every later stage uses: an even subset of each
cloud (:func:`~masknet.geometry.sampling.grid_subset`, at most ``fine_points`` source
points and eight times that of the template), the template's KD-tree and point spacing,
and which source points lie on a surface. :func:`masknet.registration.judge.fit.pose_fit` scores a
pose against it.

Why even subsets: a laser scanner's points crowd the floor and ceiling at its feet (a
fifth of a room scan lies within 30 cm of the scanner's axis). A random subset keeps that
crowd, and the fit of two scans from different places then prefers any pose that keeps
the scanners together: on two room scans taken 2 m and 41 degrees apart, the identity fit
better than the right pose on a random subset (score 0.61 against 0.50) and far worse on
an even one (0.46 against 0.76).

Example::

    pair = prepare_pair(template, source, fine_points=4096)
    pose_fit(pair.tree, pair.source[pair.surface], transform, inlier_cutoff(pair.spacing))
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from masknet._moved import moved_names
from masknet.geometry.clouds import MIN_POINTS, SPACING_SAMPLE, median_spacing
from masknet.geometry.knn import cloud_tree
from masknet.geometry.normals import plane_offsets
from masknet.geometry.sampling import grid_subset, random_subset
from masknet.registration.judge.fit import FIT_SPACINGS
from masknet.registration.terms.options import inlier_cutoff

__all__ = [
    "CHECK_MAX_DROP",
    "CHECK_NEIGHBOURS",
    "FIT_SPACINGS",
    "SURFACE_SPACINGS",
    "PreparedPair",
    "check_points",
    "isolated_free",
    "prepare_pair",
    "random_subset",
    "surface_points",
]

# A source point with no other source point within this many template spacings is
# isolated: it takes no part in the score.
SURFACE_SPACINGS = 2.0
# The check that a pose is right (the early exit, auto's fast path) counts only points
# with this many others that near: two uniform outliers that happen to lie close are no
# surface, and with 10% of them a right pose fit 0.97 instead of 0.99 (ModelNet40 pairs:
# 68% of the fast paths accepted instead of 12%, no wrong one more) ...
CHECK_NEIGHBOURS = 2
# ... unless that drops more than this share of the points: stray outliers are few (2.5%
# of the points in the median pair with 10% of them, 9% at most), and a larger share is a
# sparse part of a real scan, which a wrong pose can misfit (a pair of 4,096-point scan
# views 11 degrees off fit 0.90 in all and 0.99 without its sparse 13%).
CHECK_MAX_DROP = 0.05
# ... and no stray beside a surface: a point farther than the fit's distance from every
# other point and off the least-squares plane of its PLANE_NEIGHBOURS nearest by more than
# PLANE_SPACINGS template spacings. Uniform outliers just beside a surface have surface
# points for neighbours, so the neighbour test keeps them; at the true pose of 100
# ModelNet40 pairs with 10% outliers they held the fit under 0.99 on 21 (on 5 without
# them). Either test alone drops edges and corners (2% of a clean shape's points), which
# are what a wrong pose misfits: two flipped re-sampled shapes then passed as fitting.
# Subject to the same CHECK_MAX_DROP, applied after the neighbour test.
PLANE_SPACINGS = 1.0
PLANE_NEIGHBOURS = 8


def surface_points(
    points: np.ndarray, radius: float, spacing: float | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(P,) bool three times, from one KD-tree query of ``points`` (P, 3): those with at
    least one other point within ``radius`` (:func:`isolated_free`), those with
    ``CHECK_NEIGHBOURS``, and those that are no stray beside a surface at this template
    ``spacing`` (see ``PLANE_SPACINGS``; all of them when None). The last two are for
    :func:`check_points`."""
    k = min(len(points), max(CHECK_NEIGHBOURS, PLANE_NEIGHBOURS) + 1)
    d, idx = cloud_tree(points).query(points, k=k)
    d, idx = np.asarray(d).reshape(len(points), -1), np.asarray(idx).reshape(len(points), -1)
    one, two = d[:, min(1, k - 1)], d[:, min(CHECK_NEIGHBOURS, k - 1)]
    attached = np.ones(len(points), bool)
    if k >= 4 and spacing is not None:
        # Far from every other point at the source's own density too: a source thinner
        # than its template (a scan's subset is up to 8 times thinner) has gaps of several
        # template spacings everywhere, and its edges are no strays.
        own = np.median(one[one > 0]) if (one > 0).any() else 0.0
        alone = one > inlier_cutoff(max(spacing, own))
        # The plane of the others, not the point's: it would tilt the plane to itself.
        offsets = plane_offsets(points[alone], idx[alone, 1:].astype(np.int64), points)
        attached[alone] = offsets <= PLANE_SPACINGS * spacing
    return _most(one <= radius), _most(two <= radius), attached


def check_points(
    surface: np.ndarray, strict: np.ndarray, attached: np.ndarray | None = None
) -> np.ndarray:
    """(P,) bool: the points that the check of a pose counts: those of ``surface`` that are
    also ``strict`` (``CHECK_NEIGHBOURS`` neighbours, :func:`surface_points`), unless that
    drops more than ``CHECK_MAX_DROP`` of them (then ``surface`` itself); of those, the
    ``attached`` ones (no stray beside a surface), under the same condition."""
    kept = _unless_many(surface, surface & strict)
    return kept if attached is None else _unless_many(kept, kept & attached)


def _unless_many(points: np.ndarray, fewer: np.ndarray) -> np.ndarray:
    """``fewer``, or ``points`` where ``fewer`` drops more than ``CHECK_MAX_DROP`` of them."""
    return fewer if fewer.sum() >= (1 - CHECK_MAX_DROP) * points.sum() else points


def isolated_free(points: np.ndarray, radius: float, neighbours: int = 1) -> np.ndarray:
    """(P,) bool: points of ``points`` (P, 3) with at least ``neighbours`` other points
    within ``radius``. All True where that would keep under half of them (a cloud sparser
    than the radius)."""
    return _most(_neighbour_distances(points, neighbours)[:, -1] <= radius)


def _neighbour_distances(points: np.ndarray, neighbours: int) -> np.ndarray:
    """(P, k) distances of each point to itself and its nearest others, k <= neighbours + 1."""
    d, _ = cloud_tree(points).query(points, k=min(len(points), neighbours + 1))
    return np.asarray(d).reshape(len(points), -1)


def _most(keep: np.ndarray) -> np.ndarray:
    """``keep``, or all True where it keeps under half (a cloud sparser than the radius)."""
    return keep if keep.sum() >= max(MIN_POINTS, len(keep) // 2) else np.ones(len(keep), bool)


# The template keeps this many times the source's points (32,768 by default): a 3DMatch
# fragment of 19,000 points stays whole. Thinner templates widen the spacing that sets
# the fit's distance and ICP's pair cut-off, and moved that pair's answer from 0.70
# degrees and 8 cm off its ground truth to 1.3 degrees and 11 cm (4 times) and to 73 cm
# (twice).
TEMPLATE_FACTOR = 8


class PreparedPair(NamedTuple):
    """template: (N', 3) an even subset of the template (all of it up to
    ``TEMPLATE_FACTOR * fine_points`` points); tree: its KD-tree; spacing: its median point
    spacing, input units. source: (M', 3) an even subset of the source (all of it up to
    ``fine_points``). surface, strict, attached: (M',) bool, :func:`surface_points` of the
    source at ``SURFACE_SPACINGS`` template spacings (``attached``: at ``FIT_SPACINGS``
    and ``PLANE_SPACINGS``)."""

    template: np.ndarray
    tree: Any
    spacing: float
    source: np.ndarray
    surface: np.ndarray
    strict: np.ndarray
    attached: np.ndarray

    @property
    def checked(self) -> np.ndarray:
        """(M',) bool: the source points the check of a pose counts (:func:`check_points`)."""
        return check_points(self.surface, self.strict, self.attached)


def prepare_pair(template: np.ndarray, source: np.ndarray, fine_points: int) -> PreparedPair:
    """The :class:`PreparedPair` of template (N, 3) and source (M, 3), float64."""
    template = template[grid_subset(template, TEMPLATE_FACTOR * fine_points)]
    source = source[grid_subset(source, fine_points)]
    tree = cloud_tree(template)
    spacing = median_spacing(template, tree, sample=SPACING_SAMPLE) or 1.0
    surface, strict, attached = surface_points(source, SURFACE_SPACINGS * spacing, spacing)
    return PreparedPair(template, tree, spacing, source, surface, strict, attached)


# Moved to the one fit module (masknet.registration.judge.fit).
__getattr__ = moved_names(
    __name__,
    {name: "masknet.registration.judge.fit" for name in ("PoseFit", "pose_fit", "pose_fits")},
)
