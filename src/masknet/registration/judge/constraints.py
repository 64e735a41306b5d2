"""How firmly a fit pins a pose: the six motions' constraint by point-to-plane pairs.

A pose that fits is pinned only along the motions that move its inliers off the surfaces
they lie on. A point-to-plane pair (p on the moved source, n the template's normal at its
match) resists a small motion (turn w, slide t) by ``(p x n) . w + n . t``; over the inlier
pairs the 6 x 6 normal matrix ``A = sum(row^T row)``, rows ``[p x n, n]``, weighs every
motion at once, and an eigenvector of a small eigenvalue is a motion the fit barely feels
(degeneracy-aware ICP: Zhang, Kaess & Singh, ICRA 2016; X-ICP's localisability: Tuna et
al., T-RO 2023). On a plane a slide along it and a turn about its normal are free; on a
crease, a slide along the crease; in a corridor, a slide along the walls; on a cylinder, a
slide along and a turn about its axis.

The matrix is made unit-free: points are taken about the inliers' centroid (so that a turn
is about the overlap, not the origin) and divided by the inliers' RMS radius (so that a
turn's rows weigh what a slide of one radius does), and the eigenvalues are read as
fractions of the largest.

Example::

    constraint = pose_constraint(template, tree, moved_source, inlier_distance)
    constraint.ratios[0], describe_free(constraint, 0.02)
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from masknet.geometry.clouds import rms_radius
from masknet.geometry.normals import normals_at

__all__ = [
    "Constraint",
    "Slide",
    "best_slide",
    "covered_shares",
    "covering_pose",
    "covering_slide",
    "describe_free",
    "direction_text",
    "least_pinned",
    "free_motions",
    "pose_constraint",
]

NORMAL_NEIGHBOURS = 10  # the template's normal at a match: from its nearest points
MIN_PAIRS = 12  # fewer inlier pairs than this say nothing about the six motions
# A turn whose axis lies this many radii or more from the overlap is, over the overlap, a
# slide; it is described as one.
FAR_AXIS = 10.0


class Constraint(NamedTuple):
    """ratios: (6,) the normal matrix's eigenvalues over the largest, ascending. motions:
    (6, 6) its unit eigenvectors as columns, in the order of ``ratios``: a turn (3, radians
    times the radius) and a slide (3), for a motion of about one input unit. centre: (3,) the inliers' centroid, input
    units. radius: their RMS radius, input units. pairs: the inlier pairs counted. Both
    measured on the pairs' template points."""

    ratios: np.ndarray
    motions: np.ndarray
    centre: np.ndarray
    radius: float
    pairs: int


def pose_constraint(
    template: np.ndarray, tree: Any, moved: np.ndarray, limit: float
) -> Constraint | None:
    """The constraint of the module docstring for the source points as a pose moved them,
    ``moved`` (M, 3), against ``template`` (N, 3) and its KD-tree ``tree``
    (:func:`masknet.geometry.knn.cloud_tree`): the pairs within ``limit`` (input units).
    None where fewer than ``MIN_PAIRS`` pairs, or the pairs span no extent."""
    distances, index = tree.query(moved, k=1, distance_upper_bound=limit)
    inliers = np.isfinite(distances)
    if inliers.sum() < MIN_PAIRS:
        return None
    normals = normals_at(template, index[inliers], tree, NORMAL_NEIGHBOURS)
    # Each pair at its template point, where its normal was taken: on a curved surface a
    # source point a spacing along from its match would tilt the pair's turn by the
    # curvature (a cylinder turned about its axis read its turn pinned).
    points = template[index[inliers]]
    centre = points.mean(0)
    radius = float(rms_radius(points))
    if not radius > 0:
        return None
    rows = np.hstack([np.cross((points - centre) / radius, normals), normals])
    values, vectors = np.linalg.eigh(rows.T @ rows / len(rows))
    ratios = np.clip(values, 0.0, None) / max(values[-1], 1e-300)
    return Constraint(ratios, vectors, centre, radius, int(inliers.sum()))


def free_motions(constraint: Constraint | None, ratio: float) -> np.ndarray:
    """(K, 6) the motions (rows, in the units of :attr:`Constraint.motions`) whose
    eigenvalue is under ``ratio`` of the largest; none for no constraint."""
    if constraint is None:
        return np.zeros((0, 6))
    return constraint.motions[:, constraint.ratios < ratio].T


def direction_text(v: np.ndarray) -> str:
    """The unit direction of ``v`` (3,), e.g. ``"(0.71, 0.70, 0.00)"``."""
    unit = np.round(v / max(float(np.linalg.norm(v)), 1e-300), 2) + 0.0  # + 0.0: no -0.00
    return "(" + ", ".join(f"{x:.2f}" for x in unit) + ")"


def _point(v: np.ndarray) -> str:
    # Components a thousandth of the largest are noise about zero: written 0.
    v = np.where(np.abs(v) < 1e-3 * np.abs(v).max(), 0.0, v) + 0.0
    return "(" + ", ".join(f"{x:.3g}" for x in v) + ")"


def _signed(v: np.ndarray) -> np.ndarray:
    """``v`` with its largest component positive: a direction reads the same either way."""
    return -v if v[np.argmax(np.abs(v))] < 0 else v


def describe_free(constraint: Constraint | None, ratio: float) -> tuple[str, ...]:
    """The free motions of :func:`free_motions` in words, e.g. ``"slide along (0.71,
    0.70, 0.00)"``, ``"slide within the plane normal to (0.00, 0.00, 1.00)"``, ``"turn
    about (0.00, 0.00, 1.00) through (0.1, 2, 0.5)"`` (axis point in input units). Pure slides come first: the slides that lie within the free motions
    (on a cylinder, whose free turn and slide share an eigenvalue, any mix of the two is an
    eigenvector); what remains is named by its turn's axis, or as a slide where that axis
    lies ``FAR_AXIS`` radii or more away."""
    free = free_motions(constraint, ratio)
    if not len(free):
        return ()
    # The slides within the free span: directions t whose pure slide (0, t) the span holds.
    span = free.T @ free  # (6, 6) projector onto the free motions
    weights, slides = np.linalg.eigh(span[3:, 3:])
    pure = slides[:, weights > 0.5].T  # (S, 3)
    if len(pure) == 3:
        words = ["slide in any direction"]
    elif len(pure) == 2:  # a plane's slides: any mix of the two is free
        words = [f"slide within the plane normal to {direction_text(_signed(np.cross(*pure)))}"]
    else:
        words = [f"slide along {direction_text(_signed(t))}" for t in pure]
    rest = free - (free[:, 3:] @ pure.T) @ np.hstack([np.zeros_like(pure), pure])
    # The rest's principal motions: eigenvectors of its (6, 6) Gram matrix, largest first.
    sizes, rest_vectors = np.linalg.eigh(rest.T @ rest)
    for motion in rest_vectors.T[::-1][sizes[::-1] > 0.25][: len(free) - len(pure)]:
        turn, slide = motion[:3] / constraint.radius, motion[3:]
        # The axis of the motion x' = turn x (x - centre) + slide: its point nearest the centre.
        axis = constraint.centre + np.cross(turn, slide) / max(turn @ turn, 1e-300)
        if np.linalg.norm(axis - constraint.centre) >= FAR_AXIS * constraint.radius:
            words.append(f"slide along {direction_text(_signed(slide / np.linalg.norm(slide)))}")
        else:
            direction = _signed(turn / np.linalg.norm(turn))
            words.append(f"turn about {direction_text(direction)} through {_point(axis)}")
    return tuple(words)


def least_pinned(constraint: Constraint | None) -> str:
    """The motion ``constraint`` pins least, in the words of :func:`describe_free` (empty
    for no constraint)."""
    if constraint is None:
        return ""
    return describe_free(constraint, float(np.nextafter(constraint.ratios[0], np.inf)))[0]


# A slid pose's search: offsets along the least pinned motions' slides and their two
# diagonals, in RMS radii of the moved source. On real scan views the front end's poses slid
# along a table or a floor lay 0.27-0.45 radii from the truth, one along a diagonal of the two
# least pinned slides.
SLIDE_STEPS = tuple(0.05 * k for k in range(1, 11))
SEARCHED_MOTIONS = 2  # the least pinned motions searched along: a plane leaves two slides
# Points of each cloud (every n-th) the search ranks its slid poses on; the best one's gain
# is then measured on every point.
SEARCH_POINTS = 256


class Slide(NamedTuple):
    """gain: how much more of the overlap fits at the best slid pose than at the pose: the
    overlap fit of :mod:`masknet.registration.judge.assessment`, the worse of its two
    directions. offset: (3,) that slide, input units (zeros where none fits better)."""

    gain: float
    offset: np.ndarray


def best_slide(
    tree: Any,
    template_points: np.ndarray,
    moved: np.ndarray,
    limit: float,
    constraint: Constraint | None,
    floor: float = 0.0,
) -> Slide:
    """The slide of ``moved`` (M, 3), source points as a pose put them, along the slides of
    the ``SEARCHED_MOTIONS`` least pinned motions of ``constraint`` and their diagonals, by
    ``SLIDE_STEPS`` radii either way, that fits the template best: its points
    ``template_points`` (P, 3) and the KD-tree ``tree`` of the template, within ``limit``.
    The search fits about ``SEARCH_POINTS`` of each cloud; the gain it returns is the best
    slide's on every point. Both ways, as the verdict
    takes the overlap fit: the source's side alone rewards a slide that puts more source
    points near some surface (re-sampled scan views gained up to 4 points at their true
    pose). The gain is over the better of the pose's fit and ``floor`` (the fit at the
    verdict's nearest fit: a pose a few degrees off gains by a slide, its nearest fit more)."""

    def gains(slid: np.ndarray, base: np.ndarray) -> np.ndarray:
        return np.minimum((slid - base).min(1), slid.min(1) - max(base.min(), floor))

    def bound(source_side: np.ndarray, base: np.ndarray) -> np.ndarray:
        # A slid pose gains at most what its source side gains.
        return np.minimum(source_side - base[0], source_side - max(base.min(), floor))

    return _slide_search(tree, template_points, moved, limit, constraint, 0, gains, bound)


def covering_slide(
    tree: Any,
    template_points: np.ndarray,
    moved: np.ndarray,
    limit: float,
    constraint: Constraint | None,
) -> Slide:
    """:func:`best_slide`'s search (the same slides, arguments alike), ranked by what each
    slide covers rather than by the overlap fit: the share of each cloud's points (all of
    them, not those of the overlap) within ``limit`` of the other. The gain is the smaller
    of the two shares' gains over the pose's: a slide that lays more of the source on the
    template and more of the template under the source. The overlap fit is a share of the
    overlap, and a pose that shrinks the overlap to the part that fits reads better: a view
    of a box slid along its length, its end off the template, fitted its overlap better than
    the truth (0.83 against 0.77) and covered less of both clouds (0.97 and 0.72 of them
    against 0.99 and 0.76). :attr:`Slide.gain` is then that gain in shares of the clouds."""

    def gains(slid: np.ndarray, base: np.ndarray) -> np.ndarray:
        return (slid - base).min(1)

    def bound(source_side: np.ndarray, base: np.ndarray) -> np.ndarray:
        return source_side - base[0]

    return _slide_search(tree, template_points, moved, limit, constraint, 1, gains, bound)


def covered_shares(check: Any, pose: np.ndarray) -> np.ndarray:
    """(2,) the share of the source's and of the template's points (all of them) within the
    inlier distance of the other cloud at ``pose`` (4, 4) on ``check`` (a
    :class:`~masknet.registration.judge.prepared.PreparedCheck`): what :func:`covering_slide`
    ranks slides by."""
    from masknet.geometry.se3 import transform_points
    from masknet.registration.judge.fit import two_way_fit

    moved = transform_points(pose, check.source_points)
    return two_way_fit(check.tree, check.template_points, moved, check.limit)[:, 1]


def covering_pose(check: Any, pose: np.ndarray) -> np.ndarray | None:
    """``pose`` (4, 4) slid by :func:`covering_slide` along the least pinned motions of its
    fit on ``check`` (a :class:`~masknet.registration.judge.prepared.PreparedCheck`): (4, 4);
    None where no slide covers more of both clouds."""
    from masknet.geometry.se3 import transform_points

    moved = transform_points(pose, check.source_points)
    pinned = pose_constraint(check.template, check.tree, moved, check.limit)
    slide = covering_slide(check.tree, check.template_points, moved, check.limit, pinned)
    if not slide.gain > 0:
        return None
    slid = np.array(pose, dtype=np.float64)
    slid[:3, 3] += slide.offset
    return slid


def _slide_search(
    tree: Any,
    template_points: np.ndarray,
    moved: np.ndarray,
    limit: float,
    constraint: Constraint | None,
    column: int,
    gains: Any,
    bound: Any,
) -> Slide:
    """The search of :func:`best_slide` and :func:`covering_slide`: each side measured by
    ``column`` of :func:`~masknet.registration.judge.fit.overlap_fits` (0: the overlap fit,
    1: the share of all points within ``limit``); ``gains(slid (C, 2), base (2,))`` (C,) the
    gain of each slid pose, ``bound(source_side (C,), base (2,))`` (C,) an upper bound of it
    from the source's side alone."""
    from masknet.geometry.knn import cloud_tree
    from masknet.registration.judge.fit import overlap_fits

    none = Slide(0.0, np.zeros(3))
    if constraint is None:
        return none
    # The source slid by an offset is the template slid back by it: one tree serves all.
    source_tree = cloud_tree(moved)

    def side(near_to: Any, points: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        """(C,) the measure of ``points`` moved by each of ``offsets`` (C, 3)."""
        return overlap_fits(near_to, points[None] + offsets[:, None], limit)[:, column]

    def fits(offsets: np.ndarray, stride: tuple[int, int] = (1, 1)) -> np.ndarray:
        """(C, 2) the measure of the source and of the template at each of ``offsets``
        (C, 3), on every ``stride``-th point of each, each tree queried once for all C."""
        source, template = moved[:: stride[0]], template_points[:: stride[1]]
        return np.stack([side(tree, source, offsets), side(source_tree, template, -offsets)], 1)

    stride = (max(1, len(moved) // SEARCH_POINTS), max(1, len(template_points) // SEARCH_POINTS))
    base = fits(np.zeros((1, 3)), stride)[0]
    radius = float(rms_radius(moved))
    slides = constraint.motions[3:, :SEARCHED_MOTIONS].T  # (2, 3), orthonormalised below
    first = slides[0] / max(float(np.linalg.norm(slides[0])), 1e-300)
    second = slides[1] - (slides[1] @ first) * first
    second /= max(float(np.linalg.norm(second)), 1e-300)
    lines = (first, second, (first + second) / np.sqrt(2), (first - second) / np.sqrt(2))
    steps = (*SLIDE_STEPS, *(-s for s in SLIDE_STEPS))
    candidates = np.array([step * radius * direction for direction in lines for step in steps])
    # The template side (the other half of the queries) is fitted only where the source
    # side's bound is positive. Exact: every other slide gains nothing.
    source_side = side(tree, moved[:: stride[0]], candidates)
    hopeful = np.flatnonzero(bound(source_side, base) > 0)
    if not len(hopeful):
        return none
    template_side = side(source_tree, template_points[:: stride[1]], -candidates[hopeful])
    sampled = gains(np.stack([source_side[hopeful], template_side], 1), base)
    if not (sampled > 0).any():
        return none
    offset = candidates[hopeful[int(np.argmax(sampled))]]  # the first of the best, as a loop
    # The search's best, on every point.
    best = Slide(float(gains(fits(offset[None]), fits(np.zeros((1, 3)))[0])[0]), offset)
    return best if best.gain > 0 else none
