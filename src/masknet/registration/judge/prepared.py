"""The pair of one call, prepared once: every stage of ``auto`` and the verdict read its
views, and each view is computed on first use and kept.

:class:`PreparedPair` holds the two clouds as given to the pipeline and three kinds of
view of them, each built once per call:

* :attr:`PreparedPair.fit`, the fit's clouds (:class:`FitClouds`, :func:`fit_clouds`): an
  even subset of each cloud (:func:`~masknet.geometry.sampling.grid_subset`, at most
  ``fine_points`` source points and eight times that of the template), the template's
  KD-tree, point spacing and inlier cut-off, and which source points lie on a surface and
  which the check of a pose counts. auto's fast path, the coarse-to-fine search and its
  early exit score poses on it (:func:`masknet.registration.judge.fit.pose_fit`).
* :meth:`PreparedPair.check`, the verdict's clouds (:class:`PreparedCheck`,
  :func:`prepare_check`): even subsets of at most 32,768 points (halved where uneven), the
  template's KD-tree and the verdict's inlier distance (1.5 of the larger of the two
  spacings). :func:`~masknet.registration.judge.assessment.assess_registration` judges on
  it.
* :meth:`PreparedPair.view`, the views a stage defines: the consensus front end's voxel
  grids, their Open3D clouds with normals and the verdict's clouds on its check grid
  (:mod:`masknet.registration.stages.consensus`), built through the pair so that a call
  builds them once.

The fit's subsets and the verdict's are two views, not one: the fit keeps the template
whole up to 32,768 points and a source of ``fine_points`` (ICP's cost), the verdict both
clouds up to 32,768 and its own seeds, and each rule was calibrated on its own clouds.

Why even subsets: a laser scanner's points crowd the floor and ceiling at its feet (a
fifth of a room scan lies within 30 cm of the scanner's axis). A random subset keeps that
crowd, and the fit of two scans from different places then prefers any pose that keeps
the scanners together: on two room scans taken 2 m and 41 degrees apart, the identity fit
better than the right pose on a random subset (score 0.61 against 0.50) and far worse on
an even one (0.46 against 0.76).

Example::

    pair = PreparedPair(template, source, fine_points=4096)
    fit = pair.fit
    pose_fit(fit.tree, fit.source[fit.surface], transform, fit.limit)
    judge(pair.check(), transform)
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Hashable
from functools import cached_property
from typing import Any, NamedTuple, TypeVar

import numpy as np

from masknet._moved import moved_names
from masknet.errors import MaskNetError
from masknet.geometry.clouds import MIN_POINTS, SPACING_SAMPLE, median_spacing
from masknet.geometry.knn import cloud_tree
from masknet.geometry.normals import plane_offsets
from masknet.geometry.prepared_template import template_view
from masknet.geometry.sampling import grid_subset, random_subset
from masknet.registration.judge.fit import FIT_SPACINGS
from masknet.registration.terms.options import DEFAULT_SPACINGS, RobustOptions, inlier_cutoff

__all__ = [
    "CHECK_MAX_DROP",
    "CHECK_NEIGHBOURS",
    "FIT_SPACINGS",
    "SURFACE_SPACINGS",
    "FitClouds",
    "PreparedCheck",
    "PreparedPair",
    "check_points",
    "even_pair",
    "fit_clouds",
    "isolated_free",
    "prepare_check",
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


class FitClouds(NamedTuple):
    """The fit's view of a pair. template: (N', 3) an even subset of the template (all of it
    up to ``TEMPLATE_FACTOR * fine_points`` points); tree: its KD-tree; spacing: its median
    point spacing, input units. source: (M', 3) an even subset of the source (all of it up
    to ``fine_points``). surface, strict, attached: (M',) bool, :func:`surface_points` of
    the source at ``SURFACE_SPACINGS`` template spacings (``attached``: at
    ``FIT_SPACINGS`` and ``PLANE_SPACINGS``). checked: (M',) bool, the source points the
    check of a pose counts (:func:`check_points`)."""

    template: np.ndarray
    tree: Any
    spacing: float
    source: np.ndarray
    surface: np.ndarray
    strict: np.ndarray
    attached: np.ndarray
    checked: np.ndarray

    @property
    def limit(self) -> float:
        """The fit's inlier cut-off, input units: 1.5 template spacings."""
        return inlier_cutoff(self.spacing)


def fit_clouds(template: np.ndarray, source: np.ndarray, fine_points: int) -> FitClouds:
    """The :class:`FitClouds` of template (N, 3) and source (M, 3), float64."""
    template, tree, spacing = template_view(
        template, ("fit", fine_points), lambda: _fit_template(template, fine_points)
    )
    source = source[grid_subset(source, fine_points)]
    surface, strict, attached = surface_points(source, SURFACE_SPACINGS * spacing, spacing)
    checked = check_points(surface, strict, attached)
    return FitClouds(template, tree, spacing, source, surface, strict, attached, checked)


def _fit_template(template: np.ndarray, fine_points: int) -> tuple[np.ndarray, Any, float]:
    """The template's side of :class:`FitClouds`: its even subset (N', 3), that subset's
    KD-tree and median spacing; it depends on the template alone."""
    template = template[grid_subset(template, TEMPLATE_FACTOR * fine_points)]
    tree = cloud_tree(template)
    return template, tree, median_spacing(template, tree, sample=SPACING_SAMPLE) or 1.0


View = TypeVar("View")
_NOT_BUILT = object()


class PreparedPair:
    """One pair prepared once for a call: template (N, 3) and source (M, 3), float64, as
    the pipeline sees them, and its views (the module docstring), each built on first use
    and kept. ``fine_points``: the fit's source points (``RobustOptions.fine_points``)."""

    def __init__(
        self, template: np.ndarray, source: np.ndarray, fine_points: int | None = None
    ) -> None:
        self.template, self.source = template, source
        self.fine_points = RobustOptions.fine_points if fine_points is None else fine_points
        self._views: dict[Hashable, Any] = {}

    @cached_property
    def fit(self) -> FitClouds:
        """The fit's even subsets, tree, spacing and surface masks (:func:`fit_clouds`)."""
        return fit_clouds(self.template, self.source, self.fine_points)

    def check(self, max_correspondence_distance: float | None = None) -> PreparedCheck:
        """The verdict's clouds at this inlier distance (None: the verdict's own, 1.5 of the
        larger spacing), :func:`prepare_check`."""
        key = ("check", max_correspondence_distance)
        return self.view(
            key, lambda: prepare_check(self.template, self.source, max_correspondence_distance)
        )

    def view(self, key: Hashable, build: Callable[[], View]) -> View:
        """The view ``key``: ``build()`` on first use (None included), then the same object.
        For the views a stage defines (the consensus front end's grids)."""
        found = self._views.get(key, _NOT_BUILT)
        if found is _NOT_BUILT:
            found = self._views[key] = build()
        return found


def prepare_pair(template: np.ndarray, source: np.ndarray, fine_points: int) -> FitClouds:
    """Deprecated: the fit's view of template (N, 3) and source (M, 3), as
    ``PreparedPair(template, source, fine_points).fit`` or :func:`fit_clouds` give it (the
    next release drops this name)."""
    warnings.warn(
        "prepare_pair is deprecated: use PreparedPair(template, source, fine_points).fit "
        "(masknet.registration.judge.prepared); it goes in the next release",
        DeprecationWarning,
        stacklevel=2,
    )
    return fit_clouds(template, source, fine_points)


MAX_POINTS = 8192  # the verdict's points asked per cloud (an even subset of larger clouds)
# Larger clouds are first brought to this many points, evenly (grid_subset): a scanner's
# crowd at its feet otherwise sets the spacing and the fit. On two room scans 2 m apart,
# the right pose read `likely wrong` (19% of the overlap fitting) and the scans as given
# `likely correct` (68%).
CLOUD_POINTS = 32768
# Smaller clouds are judged on an even half (grid_subset) where their spacing more than
# doubles when an even grid keeps half their points: a random subset of a laser scan,
# whose points crowd at the scanner's feet (an even surface: 1.2-1.7 times; room scans
# thinned at random to 5,000-24,000 points: 1.9-2.7). On such room draws the right pose
# read `uncertain` at 5,000 points and `likely wrong` at 20,000 (42-46% of the overlap
# fitting), and a pose 2.2 m off `likely correct`.
UNEVEN_SPREAD = 2.0
MIN_HALVED = 2048  # ... for clouds of this many points or more: sparse objects keep theirs
NEAREST_FITS = ("point", "plane")  # the verdict's nearest fit: point-to-point, generalized
CHECK_SPACING_SAMPLE = 2048  # the verdict's spacings ask this many points of a cloud


def _subset(points: np.ndarray, count: int, seed: int) -> np.ndarray:
    return points[grid_subset(points, count, seed)]


def _spread(points: np.ndarray) -> float:
    """How much the spacing of ``points`` (P, 3) grows when an even grid keeps half of
    them: about 1.4 on an evenly sampled surface, more where a crowd sets the spacing."""
    spacing = median_spacing(points, sample=CHECK_SPACING_SAMPLE)
    half = median_spacing(_subset(points, len(points) // 2, 0), sample=CHECK_SPACING_SAMPLE)
    return half / spacing if spacing > 0 else 1.0


def even_pair(
    template: np.ndarray, source: np.ndarray, halve_uneven: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """The clouds the verdict judges, template (N, 3) and source (M, 3): even subsets of
    ``CLOUD_POINTS`` of larger clouds, the others as given; then (with ``halve_uneven``)
    an even half of each where both hold ``MIN_HALVED`` points or more and either is
    uneven (:data:`UNEVEN_SPREAD`)."""
    template = _template_subset(template, CLOUD_POINTS)
    source = _subset(source, CLOUD_POINTS, 1)
    if not halve_uneven or min(len(template), len(source)) < MIN_HALVED:
        return template, source
    spread = template_view(template, "spread", lambda: _spread(template))
    if max(spread, _spread(source)) > UNEVEN_SPREAD:
        return _template_subset(template, len(template) // 2), _subset(source, len(source) // 2, 1)
    return template, source


def _template_subset(template: np.ndarray, count: int) -> np.ndarray:
    """The template's even subset of ``count`` points (seed 0), prepared once where the
    call's template is (:func:`~masknet.geometry.prepared_template.template_view`)."""
    return template_view(
        template, ("subset", count), lambda: _subset(template, count, 0), hands_out=True
    )


class PreparedCheck(NamedTuple):
    """The verdict's view of a pair, once for many poses
    (:func:`~masknet.registration.judge.assessment.judge`).

    template: (P, 3) the template's even subset (at most ``CLOUD_POINTS``), the ICP's and
    the source-side fit's target. template_points, source_points: (P', 3), (Q, 3) the
    points asked (at most ``MAX_POINTS`` each). tree: a KD-tree of ``template``. limit:
    the inlier distance, input units. open3d: whether the nearest fit's ICP runs in
    Open3D. nearest_fit: ``"point"`` (point-to-point ICP) or ``"plane"`` (Open3D's
    generalized ICP, plane-to-plane), see :func:`prepare_check`. template_spacing: the
    median spacing of ``template`` (NaN where the inlier distance was given)."""

    template: np.ndarray
    template_points: np.ndarray
    source_points: np.ndarray
    tree: Any
    limit: float
    open3d: bool = False
    nearest_fit: str = "point"
    template_spacing: float = float("nan")


def prepare_check(
    template: np.ndarray,
    source: np.ndarray,
    max_correspondence_distance: float | None = None,
    open3d: bool = False,
    nearest_fit: str = "point",
    even: bool = True,
) -> PreparedCheck:
    """The clouds of the verdict for template (N, 3) and source (M, 3), float64, already
    checked (``register``'s inputs): even subsets, the template's KD-tree and the inlier
    distance (None: 1.5 times the larger median spacing), computed once. ``open3d``: the
    nearest fit's ICP runs in Open3D (for callers that have imported it already: the
    consensus front end). ``nearest_fit``: ``"point"``, point-to-point ICP (the default:
    on sparse symmetric shapes a fit on planes slides along the symmetry, and the truth of
    re-sampled ModelNet40 pairs read `likely correct` on 78 of 100 with ``"plane"``
    against 93); ``"plane"``, Open3D's generalized ICP, for scene scans, where a
    point-to-point fit moves a pose refined on the planes along them by more than the
    verdict's bounds (docs/RESULTS.md, "The consensus front end"). ``even``: halve uneven
    clouds (:func:`even_pair`); False for clouds already on a voxel grid."""
    if nearest_fit not in NEAREST_FITS:
        raise MaskNetError(f"nearest_fit must be one of {NEAREST_FITS}, got {nearest_fit!r}")

    even_template, even_source = even_pair(template, source, even)
    # the spacing's tree and the verdict's, built once
    tree = template_view(even_template, "tree", lambda: cloud_tree(even_template))
    spacing = float("nan")
    if max_correspondence_distance is None:
        spacing = template_view(
            even_template,
            "check spacing",
            lambda: median_spacing(even_template, tree, sample=CHECK_SPACING_SAMPLE),
        )
        spacing_source = median_spacing(even_source, sample=CHECK_SPACING_SAMPLE)
        limit = DEFAULT_SPACINGS * max(spacing, spacing_source)
    else:
        limit = float(max_correspondence_distance)
    if not limit > 0:
        raise MaskNetError("every point of a cloud is the same point: no spacing to measure by")
    return PreparedCheck(
        even_template,
        _template_subset(even_template, MAX_POINTS),
        _subset(even_source, MAX_POINTS, 1),
        tree,
        limit,
        open3d or nearest_fit == "plane",
        nearest_fit,
        spacing,
    )


# Moved to the one fit module (masknet.registration.judge.fit).
__getattr__ = moved_names(
    __name__,
    {name: "masknet.registration.judge.fit" for name in ("PoseFit", "pose_fit", "pose_fits")},
)
