"""The one fit module: how well a pose puts the source on the template, every way the
package measures it, and the guard that undoes a round that fits worse.

* :func:`inlier_fit`: Open3D's ``fitness`` and ``inlier_rmse`` (the share of source points
  within a cut-off of the template, and their RMS distance); what
  :func:`evaluate_registration` and ``register`` report.
* :func:`pose_fit` / :func:`pose_fits`: that fitness plus a truncated least-squares
  ``score``, the one score the pipelines rank poses by.
* :func:`overlap_fit`: the share of the implied overlap that fits, the verdict's measure
  (:mod:`masknet.registration.judge.assessment`).
* :class:`RoundFits`: the guard of the refined rounds (its rule,
  :func:`~masknet.registration.judge.arbiter.fits_worse`, is the arbiter's).
* :func:`evaluate_registration`: the public verb, Open3D's ``evaluate_registration`` with
  named arguments (below), and :func:`given_cut`, the check of a caller's cut-off.

Distances are in the clouds' own units; the cut-offs default to ``FIT_SPACINGS`` template
spacings, so the figures do not depend on the unit.

``evaluate_registration``: how well a transform puts the source on the template.

The same measure as Open3D's ``pipelines.registration.evaluate_registration``: a source
point is an inlier when its nearest template point, after the transform, is within
``max_correspondence_distance``; ``fitness`` is the fraction of source points that are inliers and
``inlier_rmse`` the root mean square of their distances. Unlike the ``fitness`` an ICP
run reports (which counts every pair when it has no distance cut-off), it judges any
method's result on the same footing, and says when a registration has failed.

Every argument is given by name. Open3D's function of the same name takes ``(source,
target, max_correspondence_distance, transformation)``: a call in that order would run and
measure the wrong cloud, so a positional call is a ``TypeError`` instead.

Example::

    result = register(template, source)
    quality = evaluate_registration(template=template, source=source, transform=result.transform)
    if quality.fitness < 0.3:
        print("the source barely touches the template: check the result")
"""

from __future__ import annotations

import warnings
from typing import Any, NamedTuple

import numpy as np

from masknet._moved import moved_names
from masknet.errors import MaskNetError
from masknet.geometry.clouds import SPACING_SAMPLE, median_spacing
from masknet.geometry.knn import cloud_tree
from masknet.geometry.se3 import transform_points
from masknet.registration.terms.options import DEFAULT_SPACINGS, inlier_cutoff
from masknet.registration.terms.validation import as_numpy_batch, as_rigid_transforms

__all__ = [
    "FIT_SLACK",
    "FIT_SPACINGS",
    "RESIDUAL_BAND",
    "SCORE_TRUNCATION",
    "PoseFit",
    "RegistrationQuality",
    "RoundFits",
    "covered_points",
    "evaluate_registration",
    "given_cut",
    "inlier_fit",
    "overlap_fit",
    "overlap_fits",
    "pose_fit",
    "pose_fits",
]

# The inlier distance of the score, in template spacings: evaluate_registration's default.
FIT_SPACINGS = DEFAULT_SPACINGS
# The covered points' band: template points within this many times the median distance of
# the moved source to the template are seen (covered_points), at most the inlier distance.
RESIDUAL_BAND = 3.0
# A refined round whose pose fits worse than this below its start's (pose_fit's truncated
# score, 0-1) is undone, and the rounds stop there.
FIT_SLACK = 0.02


class RegistrationQuality(NamedTuple):
    """fitness: () or (B,), the fraction of source points within
    ``max_correspondence_distance`` of the template. inlier_rmse: () or (B,), the root mean
    square distance of those points, in input units (0 where there are none, as Open3D).
    max_correspondence_distance: () or (B,), the distance used."""

    fitness: np.ndarray
    inlier_rmse: np.ndarray
    max_correspondence_distance: np.ndarray


def inlier_fit(
    template: np.ndarray, moved: np.ndarray, max_correspondence_distance: float | None = None
) -> RegistrationQuality:
    """The measure itself, for checked numpy batches: template (B, N, 3) and the source
    already moved (B, M, 3); the cut-off in their units, or None for ``DEFAULT_SPACINGS``
    template spacings. Returns (B,) arrays."""
    fitness, rmse, limits = [], [], []
    for tpl, src in zip(template, moved, strict=True):
        tree = cloud_tree(tpl)
        if max_correspondence_distance is None:
            limit = inlier_cutoff(median_spacing(tpl, tree, sample=SPACING_SAMPLE))
        else:
            limit = float(max_correspondence_distance)
        d2 = tree.query(np.ascontiguousarray(src, dtype=np.float64), k=1, sqr_dists=True)[0]
        inlier = d2 <= limit**2
        count = int(inlier.sum())
        fitness.append(count / len(d2))
        rmse.append(np.sqrt(d2[inlier].sum() / max(count, 1)))
        limits.append(limit)
    return RegistrationQuality(np.array(fitness), np.array(rmse), np.array(limits))


class PoseFit(NamedTuple):
    """fitness: fraction of points within the distance. rmse: their RMS distance.
    score: 1 - the mean of the squared distances capped at 3 times the distance, over that
    cap squared (a truncated least-squares fit, as TEASER++ scores): 1 for a perfect fit,
    0 when no point is near. Unlike a count within one radius it still ranks poses whose
    points all fall within it (sparse clouds sampled apart), and a sliding surface (a
    floor, a wall) that fits a wrong pose at one radius seldom fits at all."""

    fitness: float
    rmse: float
    score: float


SCORE_TRUNCATION = 3.0  # the score's cap, in units of the inlier distance


def pose_fit(tree: Any, points: np.ndarray, transform: np.ndarray, limit: float) -> PoseFit:
    """Fit of ``points`` (P, 3) moved by ``transform`` (4, 4) against the cloud in ``tree``."""
    return pose_fits(tree, points, transform[None], limit)[0]


def pose_fits(tree: Any, points: np.ndarray, transforms: np.ndarray, limit: float) -> list:
    """:func:`pose_fit` for each of ``transforms`` (H, 4, 4), with one KD-tree query."""
    h, p = len(transforms), len(points)
    if h == 0:
        return []
    moved = transform_points(transforms, points[None])
    d2, _ = tree.query(moved.reshape(h * p, 3), k=1, sqr_dists=True)
    d2 = d2.reshape(h, p)
    inlier = d2 <= limit**2
    count = inlier.sum(1)
    rmse = np.sqrt(np.where(inlier, d2, 0.0).sum(1) / np.maximum(count, 1))
    # Truncated least squares: each point's squared distance, capped, so that points with
    # no counterpart (outliers, the part the other cloud does not see) weigh alike.
    cap = (SCORE_TRUNCATION * limit) ** 2
    score = 1.0 - np.minimum(d2, cap).mean(1) / cap
    return [
        PoseFit(c / p, float(r), float(sc)) for c, r, sc in zip(count, rmse, score, strict=True)
    ]


class RoundFits:
    """The refined rounds' guard, for template (B, N, 3) and source (B, M, 3): the fit of a
    pose (:func:`pose_fit`'s truncated score, 0-1, at 1.5
    template spacings, one KD-tree per template built once). A learned back-end such as
    PointNetLK can leave a pair further off than it started; on the README's sample pair
    its second round went from 24.5 to 61 degrees, its fit from 0.57 to 0.35."""

    def __init__(self, template: np.ndarray, source: np.ndarray) -> None:
        self.trees = [cloud_tree(t) for t in template]
        self.limits = [
            inlier_cutoff(median_spacing(t, tree, SPACING_SAMPLE) or 1.0)
            for t, tree in zip(template, self.trees, strict=True)
        ]
        self.source = source
        self.settled = np.zeros(len(template), bool)
        self.scores: np.ndarray | None = None

    def _scores(self, poses: np.ndarray) -> np.ndarray:
        return np.array(
            [
                pose_fit(tree, points, pose, limit).score
                for tree, points, pose, limit in zip(
                    self.trees, self.source, poses, self.limits, strict=True
                )
            ]
        )

    def keep_no_worse(self, start: np.ndarray, reached: np.ndarray) -> np.ndarray:
        """(B, 4, 4): ``reached`` (B, 4, 4) where it fits no worse than ``start`` (B, 4, 4)
        by more than FIT_SLACK, else ``start``; a pair kept at its start once stays there."""
        from masknet.registration.judge.arbiter import fits_worse

        if self.scores is None:  # the first guarded round: round 1's poses
            self.scores = self._scores(start)
        new = self._scores(reached)
        self.settled |= fits_worse(new, self.scores)
        self.scores = np.where(self.settled, self.scores, new)
        return np.where(self.settled[:, None, None], start, reached)


def overlap_fit(
    near_to: Any, points: np.ndarray, limit: float, near: float = 3.0
) -> tuple[float, float, float]:
    """(share within ``limit`` among points within ``near`` x ``limit``, share within
    ``limit``, share within ``near`` x ``limit``) of ``points`` (P, 3) against the cloud of the
    KD-tree ``near_to``: the overlap fit of :mod:`masknet.registration.judge.assessment`."""
    shares = overlap_fits(near_to, np.asarray(points)[None], limit, near)[0]
    return float(shares[0]), float(shares[1]), float(shares[2])


def two_way_fit(
    tree: Any, template_points: np.ndarray, moved: np.ndarray, limit: float, near: float = 3.0
) -> np.ndarray:
    """(2, 3) :func:`overlap_fit`'s three shares both ways: row 0 the moved source points
    ``moved`` (M, 3) against the template's KD-tree ``tree``, row 1 the template's points
    ``template_points`` (P, 3) against the moved source (a tree of it built here)."""
    from masknet.geometry.knn import cloud_tree

    source_side = overlap_fit(tree, moved, limit, near)
    return np.array([source_side, overlap_fit(cloud_tree(moved), template_points, limit, near)])


def overlap_fits(near_to: Any, points: np.ndarray, limit: float, near: float = 3.0) -> np.ndarray:
    """(C, 3) :func:`overlap_fit`'s three shares for each of C clouds ``points`` (C, P, 3)
    (one cloud moved C ways), the KD-tree queried once for all."""
    count, size = points.shape[:2]
    d, _ = near_to.query(points.reshape(-1, 3), k=1, distance_upper_bound=near * limit)
    d = d.reshape(count, size)
    within = np.isfinite(d).sum(1)
    close = (d <= limit).sum(1)
    return np.stack([close / np.maximum(within, 1), close / size, within / size], axis=1)


def covered_points(
    template: np.ndarray, moved_source: np.ndarray, limit: float, template_tree: Any = None
) -> np.ndarray:
    """(N,) bool: the template points (N, 3) that the source, as a pose moved it (M, 3),
    saw: the overlap mask the pipelines return for a pose.

    Two kinds of evidence, both within ``limit`` (the fit's inlier distance):

    - each source point within ``limit`` claims its nearest template point: an observation
      accounts for the point under it (at an exact pose on copied points this alone is the
      true mask);
    - a template point is seen where the source passes within the band its own residuals
      allow: ``RESIDUAL_BAND`` times the median distance of the source points to the
      template, capped at ``limit``. A source sampled apart from the template (a re-scan)
      leaves residuals of about half a spacing, and the band covers the surface between its
      points; a pose exact on copied points leaves none, and the band adds nothing at the
      seen region's edge, where a fixed ``limit`` took in a spacing's worth of unseen points
      (top-k precision 0.957 against 1.000 on ModelNet40 test pairs).

    ``template_tree``: a KD-tree of ``template`` already built (the prepared pair's, where
    its fit view holds the whole template), else one is built here.
    """
    from masknet.geometry.knn import cloud_tree

    to_source = cloud_tree(moved_source).query(template, k=1)[0]
    tree = cloud_tree(template) if template_tree is None else template_tree
    to_template, nearest = tree.query(moved_source, k=1)
    on_template = to_template <= limit
    band = min(limit, RESIDUAL_BAND * float(np.median(to_template))) if len(moved_source) else 0.0
    covered = to_source <= band
    covered[nearest[on_template]] = True
    return covered


def given_cut(
    max_correspondence_distance: float | None, max_distance: float | None, function: str
) -> float | None:
    """The cut-off a caller gave, checked: ``max_correspondence_distance``, or the
    deprecated ``max_distance`` with a DeprecationWarning (not both); None if neither."""
    if max_distance is not None:
        if max_correspondence_distance is not None:
            raise MaskNetError(f"{function}: give max_correspondence_distance only")
        warnings.warn(
            f"{function}(max_distance=...) is deprecated; use max_correspondence_distance=, "
            "Open3D's name",
            DeprecationWarning,
            stacklevel=3,
        )
        max_correspondence_distance = max_distance
    cut = max_correspondence_distance
    if cut is not None and (
        isinstance(cut, bool | np.bool_)
        or not isinstance(cut, int | float | np.number)
        or not (np.isfinite(cut) and cut > 0)
    ):
        raise MaskNetError(f"max_correspondence_distance must be a positive number, got {cut!r}")
    return None if cut is None else float(cut)


def evaluate_registration(
    *,
    template: np.ndarray,
    source: np.ndarray,
    transform: np.ndarray,
    max_correspondence_distance: float | None = None,
    max_distance: float | None = None,
) -> RegistrationQuality:
    """Inlier fraction and RMSE of ``source`` moved by ``transform`` against ``template``.

    Keyword arguments only (``evaluate_registration(template=t, source=s, transform=T)``):
    Open3D's ``evaluate_registration`` takes the source first, and a call in its order
    would measure the wrong cloud.

    Args:
        template: (N, 3) or (B, N, 3) points.
        source: (M, 3) or (B, M, 3) points.
        transform: (4, 4) or (B, 4, 4) source -> template, as ``register`` returns it.
        max_correspondence_distance: inlier cut-off in input units (Open3D's name); None
            takes ``DEFAULT_SPACINGS`` times each template's median nearest-neighbour
            distance (over a seeded subset of 4,096 points for larger templates), so the
            result does not depend on the unit.
        max_distance: the former name of ``max_correspondence_distance``, deprecated.

    Returns:
        RegistrationQuality, unbatched for unbatched clouds.

    Raises:
        MaskNetError: bad clouds (shape, NaN/inf, too few points) or a bad transform
            or cut-off.
    """
    cut = given_cut(max_correspondence_distance, max_distance, "evaluate_registration")
    template_b, source_b, single = as_numpy_batch(template, source)
    tf = as_rigid_transforms(transform, template_b.shape[0])
    quality = inlier_fit(template_b, transform_points(tf, source_b), cut)
    if single:
        return RegistrationQuality(*(a[0] for a in quality))
    return quality


# Moved to the arbiter (masknet.registration.judge.arbiter), with every rule between poses.
__getattr__ = moved_names(__name__, {"fits_worse": "masknet.registration.judge.arbiter"})
