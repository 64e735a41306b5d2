"""``assess_registration``: did a registration work? A verdict with its reason.

The share of source points that land near the template (``fitness``) cannot say: two
partial scans at their true pose may overlap by a quarter, and a wrong pose of two room
scans can fit as well as the right one. The verdict rests on two unit-free figures:

* **The overlap fit.** The points that the pose brings near the other cloud (within 3
  inlier distances) are the overlap it implies. On a right pose almost all of them lie
  within one inlier distance (1.5 spacings), because the surfaces coincide there; on a
  wrong pose surfaces only cross, and about half do. It is taken both ways, template to
  source and source to template, and the smaller counts.
* **The nearest fit.** A short ICP (cut-off 3 inlier distances) starts from the pose.
  How far it turns and shifts the source says whether the pose is on a fit or some
  degrees from one; the overlap fit is measured there, at the nearest fit.

Verdicts: ``likely wrong`` when the overlap fit is under 0.5, or the nearest fit lies 8
degrees or 15% of the source's radius away; ``likely correct`` when the overlap fit is at
least 0.6 and the nearest fit lies within 3 degrees and 7.5% of the radius; ``uncertain``
otherwise. Calibrated on ground-truth poses and poses turned 2, 5, 15
and 45 degrees off (docs/RESULTS.md, "Did it work?", ``masknet benchmark success``).

Clouds of over 32,768 points are judged on even subsets (one point per voxel,
:func:`masknet.geometry.sampling.grid_subset`): a laser scan's crowd at the scanner's feet
would otherwise set the spacing and the fit, and the verdict would favour any pose that
keeps two scanners together. Then, where both clouds hold 2,048 points or more and one
of them is uneven (a random subset of a laser scan), both are judged on even halves:
:func:`even_pair`.

A result that is the right fit of an ambiguous shape (a flip of a symmetric object) is
``likely correct`` here: the verdict judges the fit, and ``result.info["ambiguous"]``
says whether another pose fits as well.

Example::

    result = register(template, source)
    check = assess_registration(template, source, result.transform)
    print(check.verdict, "-", check.reason)
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from masknet.geometry.clouds import rms_radius
from masknet.geometry.se3 import transform_points
from masknet.registration.judge.constraints import (
    Slide,
    best_slide,
    describe_free,
    direction_text,
    least_pinned,
    pose_constraint,
)
from masknet.registration.judge.fit import given_cut, two_way_fit
from masknet.registration.judge.fit import overlap_fit as implied_overlap_fit
from masknet.registration.judge.hypotheses import rotation_between_deg

# The verdict's clouds are a view of the call's prepared pair (judge/prepared.py); their
# builder and its figures are importable here as before.
from masknet.registration.judge.prepared import (  # noqa: F401
    CLOUD_POINTS,
    MAX_POINTS,
    MIN_HALVED,
    NEAREST_FITS,
    UNEVEN_SPREAD,
    PreparedCheck,
    PreparedPair,
    even_pair,
    prepare_check,
)
from masknet.registration.terms.units import warn_mixed_units
from masknet.registration.terms.validation import as_numpy_batch, as_rigid_transforms

__all__ = [
    "Assessment",
    "PreparedCheck",
    "RULE_VERDICTS",
    "assess_registration",
    "judge",
    "prepare_check",
    "verdict_rule",
]

NEAR = 3.0  # the overlap a pose implies: points within this many inlier distances
NEAR_ITERATIONS = 20  # the short ICP that finds the nearest fit
CORRECT_FIT, WRONG_FIT = 0.6, 0.5  # overlap fit: likely correct at or above, wrong below
CORRECT_DEG, WRONG_DEG = 3.0, 8.0  # the nearest fit's turn: correct within, wrong from
CORRECT_SHIFT, WRONG_SHIFT = 0.075, 0.15  # its shift, in RMS radii of the moved source
# A motion is free where the inlier pairs' point-to-plane normal matrix weighs it under this
# share of its firmest motion (masknet.registration.judge.constraints): the fit does not pin the
# pose along it, and a pose slid that way fits as well.
FREE_RATIO = 2e-4
# A pose slid along its least pinned motions that fits this much more of the source's
# overlap (masknet.registration.judge.constraints.best_slide) makes the pose likely wrong.
SLIDE_GAIN = 0.035
# The front end's start slid to cover more (masknet.registration.stages.consensus) is judged
# only where, refined, it covers this much more of each cloud than the start (shares of all
# points within the inlier distance: masknet.registration.judge.constraints.covered_shares).
COVER_GAIN = 0.01
VERDICTS = ("likely correct", "uncertain", "likely wrong")
# Which rule of verdict_rule decided, and the verdict it gives.
RULE_VERDICTS = {
    "overlap": "likely wrong",  # under WRONG_FIT of the overlap fits
    "nearby": "likely wrong",  # a fit WRONG_DEG or WRONG_SHIFT away
    "slid": "likely wrong",  # a slide along a least pinned motion fits SLIDE_GAIN better
    "free": "uncertain",  # "correct", but a motion is free (FREE_RATIO): not pinned
    "correct": "likely correct",  # CORRECT_FIT, within CORRECT_DEG and CORRECT_SHIFT
    "between": "uncertain",  # none of the above
}


def verdict_rule(
    overlap_fit: float,
    nearby_deg: float,
    nearby_shift: float,
    constraint: float = 1.0,
    slide_gain: float = 0.0,
) -> str:
    """The rule that decides the verdict (a key of :data:`RULE_VERDICTS`), from the overlap
    fit at the nearest fit, how far that fit lies (degrees, and the source centroid's
    shift over its RMS radius), how firmly it pins its least pinned motion
    (``constraint``, :attr:`Assessment.constraint`) and how much better a pose slid along
    such motions fits (``slide_gain``, :attr:`Assessment.slide_gain`). The rules apply in
    this order."""
    if overlap_fit < WRONG_FIT:
        return "overlap"
    if nearby_deg >= WRONG_DEG or nearby_shift >= WRONG_SHIFT:
        return "nearby"
    if slide_gain >= SLIDE_GAIN:
        return "slid"
    if overlap_fit >= CORRECT_FIT and nearby_deg <= CORRECT_DEG and nearby_shift <= CORRECT_SHIFT:
        return "free" if constraint < FREE_RATIO else "correct"
    return "between"


class Assessment(NamedTuple):
    """verdict: ``likely correct``, ``uncertain`` or ``likely wrong``. reason: one line
    saying why. overlap_fit: the smaller of the two directions' share of overlap points
    within ``max_correspondence_distance``. fitness: the share of source points within
    it (Open3D's fitness; over an even subset of 8,192 points for larger
    sources). overlap: the share of source points in the
    overlap (within 3 times that distance). nearby_deg, nearby_shift: how far a short ICP
    from the pose moves it, as a rotation in degrees and as the shift of the source's
    centroid over its RMS radius. max_correspondence_distance: the inlier distance, input
    units. constraint: how firmly the fit at the pose pins its least pinned motion, the
    smallest eigenvalue of its inlier pairs' point-to-plane normal matrix over the largest
    (:func:`~masknet.registration.judge.constraints.pose_constraint`; 1.0 where under a dozen
    pairs fit). free_directions: the motions it leaves free (under :data:`FREE_RATIO`) in
    words, e.g. ``("slide along (0.71, 0.70, 0.00)",)``; empty where the fit pins the
    pose. least_pinned: the motion it pins least, in those words, free or not (empty where
    under a dozen pairs fit). slide_gain: how much more of the overlap (both ways) fits at
    the pose slid along its two least pinned motions (up to half the radius) than
    at the pose or its nearest fit (:func:`~masknet.registration.judge.constraints.best_slide`;
    0 where the overlap fit or a nearby fit already makes the pose ``likely wrong``: no slide
    is searched). rule: the rule of :func:`verdict_rule` that decided (a key of
    :data:`RULE_VERDICTS`: ``"free"`` is a pose that fits as right poses do, which no slide
    along its free motions fits better, but which the fit does not pin)."""

    verdict: str
    reason: str
    overlap_fit: float
    fitness: float
    overlap: float
    nearby_deg: float
    nearby_shift: float
    max_correspondence_distance: float
    constraint: float = 1.0
    free_directions: tuple[str, ...] = ()
    slide_gain: float = 0.0
    least_pinned: str = ""
    rule: str = ""


def _nearest_fit(prepared: PreparedCheck, transform: np.ndarray) -> np.ndarray:
    """The pose (4, 4) that a short ICP reaches from ``transform``: at most
    ``NEAR_ITERATIONS``, pairs cut at ``NEAR`` inlier distances. Open3D's generalized ICP
    where the pair was prepared with ``nearest_fit="plane"`` (scans). Otherwise
    point-to-point: Open3D's ICP where the
    pair was prepared for it (on a few hundred points, half the verdict's time), the
    project's numpy ICP otherwise, so that a verdict never pays for importing Open3D: the
    same algorithm (on 600 poses of sparse pairs, right and 2-45 degrees off, the two gave
    the same verdict on 599). Not point-to-plane: on sparse symmetric shapes it slides
    along the symmetry at no cost, and the truth read `likely wrong` (docs/RESULTS.md,
    "Sparse clouds: the consensus front end first")."""
    cut = NEAR * prepared.limit
    if prepared.open3d:
        from masknet.registration.solvers.open3d_icp import open3d_icp

        # Open3D's RMSE criterion is absolute: given in inlier distances, it does not
        # depend on the unit (the numpy ICP's is relative to the RMSE).
        found = open3d_icp(
            prepared.template,
            prepared.source_points,
            transform,
            NEAR_ITERATIONS,
            cut,
            relative_rmse=1e-6 * prepared.limit,
            generalized=prepared.nearest_fit == "plane",
        )
        return found.transform[0].numpy()
    from masknet.registration.solvers.icp import icp

    return icp(
        prepared.template,
        prepared.source_points,
        init=transform,
        max_iterations=NEAR_ITERATIONS,
        max_correspondence_distance=cut,
        template_tree=prepared.tree,
    ).transform[0]


def assess_registration(
    template: np.ndarray,
    source: np.ndarray,
    transform: np.ndarray,
    *,
    max_correspondence_distance: float | None = None,
    max_distance: float | None = None,
) -> Assessment:
    """Judge ``transform`` (source -> template) for one pair.

    Args:
        template: (N, 3) points.
        source: (M, 3) points.
        transform: (4, 4) rigid source -> template, as ``register`` returns it.
        max_correspondence_distance: the inlier distance in input units (Open3D's name);
            None takes 1.5 times the larger of the two clouds' median spacings (exact
            duplicates skipped), so the verdict does not depend on the unit.
        max_distance: the former name of ``max_correspondence_distance``, deprecated.

    Raises:
        MaskNetError: bad clouds (shape, NaN/inf, too few points), a batch, or a
            transform that is not rigid.
    """
    from masknet.errors import MaskNetError

    max_distance = given_cut(max_correspondence_distance, max_distance, "assess_registration")
    template_b, source_b, single = as_numpy_batch(template, source)
    if not single:
        raise MaskNetError("assess_registration judges one pair: (N, 3) and (M, 3) clouds")
    tf = as_rigid_transforms(transform, 1)[0]
    warn_mixed_units(template_b[0], source_b[0])
    return judge(PreparedPair(template_b[0], source_b[0]).check(max_distance), tf)


def judge(prepared: PreparedCheck, transform: np.ndarray) -> Assessment:
    """The verdict of the module docstring on a pair's verdict view (a
    :class:`~masknet.registration.judge.prepared.PreparedCheck`: ``PreparedPair.check()``,
    or the consensus front end's on its check grid) for ``transform`` (4, 4), rigid,
    source -> template (no checks: the pipelines' own poses)."""

    limit, template_tree = prepared.limit, prepared.tree

    def moved_by(pose: np.ndarray) -> np.ndarray:
        return transform_points(pose, prepared.source_points)

    refined = _nearest_fit(prepared, transform)
    moved, nearest = moved_by(transform), moved_by(refined)
    _, fitness, overlap = implied_overlap_fit(template_tree, moved, limit, NEAR)
    # The fit of the nearest fitting pose: the surfaces there, not a few spacings off.
    overlap_fit = float(
        two_way_fit(template_tree, prepared.template_points, nearest, limit, NEAR)[:, 0].min()
    )
    nearby_deg = rotation_between_deg(refined, transform)
    radius = rms_radius(moved)
    nearby_shift = float(np.linalg.norm(nearest.mean(0) - moved.mean(0)) / max(radius, 1e-300))
    away = f"{nearby_deg:.1f} degrees and {nearby_shift:.0%} of the radius away"
    # The worse direction is usually template to source: a partial view's edge leaves
    # template points a little beyond it, so a right pose of a view reads under 100%.
    fits = (
        f"{overlap_fit:.0%} of the overlap fits within {limit:.3g} (input units; the worse "
        f"of the two directions)"
    )
    # How firmly the fit pins the pose: on a plane, a crease or a corridor a slid pose fits
    # the surfaces it lies on as well as the right one. Measured at the pose, not at the
    # nearest fit: on scans a point-to-point nearest fit slides off a right pose, and a
    # slide back from there fits better.
    pinned = pose_constraint(prepared.template, template_tree, moved, limit)
    constraint = 1.0 if pinned is None else float(pinned.ratios[0])
    free = describe_free(pinned, FREE_RATIO)
    slide = Slide(0.0, np.zeros(3))  # no slide is searched where the verdict is already wrong
    if RULE_VERDICTS[verdict_rule(overlap_fit, nearby_deg, nearby_shift)] != "likely wrong":
        slide = best_slide(
            template_tree, prepared.template_points, moved, limit, pinned, overlap_fit
        )
    rule = verdict_rule(overlap_fit, nearby_deg, nearby_shift, constraint, slide.gain)
    verdict = RULE_VERDICTS[rule]
    if rule == "overlap":
        reason = (
            f"only {fits} at the nearest fit ({away}); right poses fit {CORRECT_FIT:.0%} or more"
        )
    elif rule == "nearby":
        reason = f"a pose {away} fits better"
    elif rule == "slid":
        offset = np.linalg.norm(slide.offset)
        reason = (
            f"a pose slid {offset:.3g} (input units) along {direction_text(slide.offset)} from "
            f"the nearest fit ({away}) fits {slide.gain:.0%} more of the overlap"
        )
    elif rule == "free":
        reason = (
            f"at the nearest fit ({away}), {fits}, but the fit does not pin the pose: free "
            f"to {' and to '.join(free)}"
        )
    else:
        reason = f"at the nearest fit ({away}), {fits}"
    if free and rule != "free":
        reason += f"; the fit leaves the pose free to {' and to '.join(free)}"
    return Assessment(
        verdict,
        reason,
        overlap_fit,
        fitness,
        overlap,
        nearby_deg,
        nearby_shift,
        limit,
        constraint,
        free,
        slide.gain,
        least_pinned(pinned),
        rule,
    )
