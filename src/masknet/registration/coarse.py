"""``method="robust"``: coarse-to-fine registration of one pair from two kinds of hypotheses.

ICP, masked or not, stops in the nearest local minimum, so the pose it starts from decides
the result. This pipeline gathers starting poses from two sources that fail in different
places, scores them all with one fit, and refines only the best:

1. **Correspondences** (:mod:`masknet.registration.correspondences`). FPFH features on a
   voxel grid that leaves about ``feature_points`` template points (so the unit does not
   matter; normals turned towards each cloud's centroid), nearest-neighbour matches both
   ways, and a batched RANSAC that returns the ``correspondence_hypotheses`` best distinct
   poses; where a grid has 150 matches or more, ``compatibility_hypotheses`` more from
   groups of mutually compatible matches (found where too few matches are right for
   RANSAC to draw three). Strong on dense clouds and real scans, whatever the rotation.
2. **Early exit.** When the best of those fits as a correct result does (``fitness`` of at
   least ``accept_fitness`` at 1.5 template spacings, the measure of
   :func:`~masknet.registration.evaluate_registration`, over the source points that
   :func:`check_points` keeps), the search stops there. No network runs.
3. **The learned side**, otherwise. The two-sided MaskNet masks both clouds once (the
   template's overlap, the source's outliers). Matches that touch a rejected point are
   dropped and RANSAC runs again on the rest; and the kept source, centred on the masked
   template's centroid, starts from each of ``hypotheses`` rotations (the 24 rotations of
   the cube) through ``max_iterations`` of ICP at ``hypothesis_points`` points (a
   sixteenth of larger clouds). This is where sparse or re-sampled objects, whose FPFH
   features say little, are found.
4. **One score** for every hypothesis: the fitness of the kept source points against the
   whole template, from one KD-tree built once, ties broken by the inlier RMSE.
5. **Refinement of the best ``candidates``**, one per basin (``distinct_deg`` or a tenth
   of the template's radius apart): ``inlier_iterations`` of ICP on the kept source with
   pairs cut at ``max_correspondence_distance`` (1.5 template spacings); rescored, the
   best wins.
6. **Ambiguity.** When answers fit within ``ambiguity_margin`` of the best, each is first
   refined as far as it goes (pairs cut at twice ``max_correspondence_distance``, then at it) and
   scored again; among those still alike, the least rotation from the pose as given
   wins. When a pose at least ``distinct_deg`` away still fits within the margin (a
   symmetric shape), the result says so (``info["ambiguous"]``, with the runner-up's
   transform and fitness).

Everything runs on one pair in numpy and KD-trees; stage times go to ``times``
(``features``, ``ransac``, ``mask``, ``hypotheses``, ``refine``).

Example::

    result = register(template, source, method="robust")
    result.info["path"], result.info["ambiguous"]
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from masknet.geometry.clouds import MIN_POINTS
from masknet.geometry.knn import cloud_tree
from masknet.geometry.sampling import spread_labels
from masknet.geometry.se3 import hypothesis_rotations, rotation_angle_deg, transform_points
from masknet.registration.correspondences import (
    FeatureCloud,
    compatible_poses,
    feature_cloud,
    mutual_matches,
    ransac_poses,
    voxel_for,
)
from masknet.registration.icp import icp, icp_from_starts
from masknet.registration.options import RobustOptions
from masknet.registration.prepared import (
    FIT_SPACINGS,
    PreparedPair,
    pose_fit,
    pose_fits,
    prepare_pair,
    random_subset,
)

__all__ = ["REFINE_TOLERANCE", "CoarseRun", "coarse_to_fine", "rotation_between_deg"]

# The refinement's ICP stops once its mean squared error changes by less than this
# fraction: finer steps move a pose by far less than its error.
REFINE_TOLERANCE = 5e-6


# Compatible groups of matches (:func:`compatible_poses`) join RANSAC's hypotheses where a
# grid has at least this many matches (templates of a few thousand points). On 105
# re-sampled 4,096-point scan views they took the first round's mean from 3.46 to 1.76
# degrees; on 512- and 1,024-point clouds (30-90 matches a grid) the groups are too small
# to agree by more than chance, and on re-sampled ModelNet40 shapes they took `robust`
# from 6.6 to 8.5 degrees.
COMPATIBILITY_MIN_MATCHES = 150


# Candidates for refinement lie in different basins: at least distinct_deg or this share
# of the template's radius apart. Poses closer than that refine into one answer, and a
# tighter test (1.5 template spacings) let three copies of one symmetric flip, a few
# spacings apart, fill every candidate place on a scan view whose true pose ranked fourth
# (returned 180 degrees off; with this test 5.8 degrees, refined to 0.1 by the loop).
CANDIDATE_BASIN = 0.1


# The early exit's check of the clouds as they are (:func:`_as_given`) refines them only
# when their short ICP fits at most this far below the best answer (the flipped pair's
# start: 0.920 against 0.967).
AS_GIVEN_GAP = 0.1


class CoarseRun(NamedTuple):
    """transform: (4, 4) source -> template. mask: (N,) bool template points within the
    inlier distance of the moved kept source, or None without masks. source_mask: (M,)
    bool source points kept, or None without a two-sided network. info: ``path`` (``"correspondences"``: the
    early exit; ``"search"``: the learned side ran), ``source`` of the winning hypothesis
    (``"fpfh"``, ``"fpfh-masked"``, ``"rotation"``), ``fitness`` and ``inlier_rmse`` (the
    score's, input units), ``ambiguous`` (bool), ``runner_up`` ((4, 4) or None) and
    ``runner_up_fitness``, ``score`` and ``runner_up_score`` (:class:`PoseFit`),
    ``hypotheses`` (how many were scored)."""

    transform: np.ndarray
    mask: np.ndarray | None
    source_mask: np.ndarray | None
    info: dict


def rotation_between_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle in degrees between the rotations of transforms ``a`` and ``b`` (4, 4)."""
    return float(rotation_angle_deg(a[:3, :3].T @ b[:3, :3]))


MaskFunction = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def coarse_to_fine(
    template: np.ndarray,
    source: np.ndarray,
    predict_masks: MaskFunction | None,
    options: RobustOptions,
    times: dict[str, float],
    prepared: PreparedPair | None = None,
) -> CoarseRun:
    """The pipeline of the module docstring for template (N, 3) and source (M, 3), float64
    numpy, at any size: the features see the whole clouds, the fit and ICP the even
    subsets of :func:`~masknet.registration.prepared.prepare_pair` (``prepared``: that of
    this pair, already made).

    ``predict_masks(template, source)`` gives the network's masks over the clouds it is
    given ((N,) and (M,) bool: the template's overlap, the source's kept points); None
    searches without masks."""
    full_source, full_template = source, template

    def clock(stage: str, since: float) -> float:
        now = time.perf_counter()
        times[stage] = times.get(stage, 0.0) + now - since
        return now

    tic = time.perf_counter()
    if prepared is None:
        prepared = prepare_pair(full_template, full_source, options.fine_points)
    template, tree, spacing, source = prepared[:4]
    limit = FIT_SPACINGS * spacing
    radius = float(np.linalg.norm(template - template.mean(0), axis=1).max())
    # Isolated source points (uniform outliers, stray returns) would cap every pose's
    # fitness below what a correct pose reaches: the score counts the rest.
    surface, checked = prepared.surface, prepared.checked
    small = options.hypothesis_size(len(source))  # points of the hypotheses' short ICP
    probe = random_subset(source[surface], small * 2)
    scored: list[Scored] = []

    def refine(pose: np.ndarray, points: np.ndarray, kind: str, loose: bool = False) -> Scored:
        """ICP from ``pose`` with pairs cut at ``max_correspondence_distance`` (first at twice that
        with ``loose``), scored on ``points``. The tight cut-off alone can stop a few
        degrees short: from 3 degrees off a clean pair it settled 1.1 degrees off, where
        a looser one first reaches the exact pose."""
        tf = pose
        for cut in ((2 * options.cut(spacing),) if loose else ()) + (options.cut(spacing),):
            tf = icp(
                template,
                points,
                tf,
                options.inlier_iterations,
                REFINE_TOLERANCE,
                max_correspondence_distance=cut,
                template_tree=tree,
            ).transform[0]
        return Scored(*pose_fit(tree, points, tf, limit), tf, kind)

    # 1. Correspondence hypotheses at each grid, in order, scored as RANSAC left them;
    # the best two refined, and the search ends at the first grid whose best fits.
    grids: list[tuple[FeatureCloud, FeatureCloud, np.ndarray]] = []  # source, template, matches

    def correspondence_poses(grid: tuple, pairs: np.ndarray, kind: str, points: np.ndarray):
        found = ransac_poses(
            grid[0].points[pairs[:, 0]],
            grid[1].points[pairs[:, 1]],
            1.5 * grid[0].voxel,
            trials=options.ransac_trials,
            keep=options.correspondence_hypotheses,
        )
        poses = found.transform
        if len(pairs) >= COMPATIBILITY_MIN_MATCHES:
            compatible = compatible_poses(
                grid[0].points[pairs[:, 0]],
                grid[1].points[pairs[:, 1]],
                1.5 * grid[0].voxel,
                seeds=options.compatibility_hypotheses,
            )
            poses = np.concatenate([poses, compatible.transform])
        fits = pose_fits(tree, points, poses, limit)
        scored.extend(Scored(*f, p, kind) for f, p in zip(fits, poses, strict=True))

    early: list[Scored] | None = None
    kept_source = source[surface]
    if _has_open3d() and options.correspondence_hypotheses:
        # A larger template gets finer grids: features of a room at an object's
        # resolution would see walls and little else.
        growth = float(np.clip(np.sqrt(len(full_template) / 1024), 1, 8))
        voxels = [
            max(voxel_for(full_template, int(count * growth), radius), spacing)
            for count in options.feature_points
        ]
        for voxel in dict.fromkeys(voxels):  # two grids may come out alike on small clouds
            grid_s = feature_cloud(full_source, voxel)
            grid_t = feature_cloud(full_template, voxel)
            grid = (grid_s, grid_t, mutual_matches(grid_s.features, grid_t.features))
            grids.append(grid)
            tic = clock("features", tic)
            before = len(scored)
            correspondence_poses(grid, grid[2], "fpfh", probe)
            if len(scored) > before:
                # The two best distinct poses, refined: a symmetric shape's flip can lead
                # RANSAC's ranking, and a close second makes the answer ambiguous. A
                # second that fits AS_GIVEN_GAP below the best is neither (it seldom
                # climbs that far), and its refinement is skipped.
                # This grid's own: an earlier grid's best were refined already.
                tops = _distinct(sorted(scored[before:], key=_rank, reverse=True), 2, limit)
                tops = [s for s in tops if s.score >= tops[0].score - AS_GIVEN_GAP]
                refined = [refine(s.pose, kept_source, "fpfh") for s in tops]
                check = pose_fits(tree, source[checked], np.stack([f.pose for f in refined]), limit)
                if max(f.fitness for f in check) >= options.accept_fitness:
                    early = refined
            tic = clock("ransac", tic)
            if early is not None:
                break
    mask = source_mask = None
    if early is not None:
        start = _short_icp_from_identity(template, kept_source, small, options.max_iterations)
        finals = early + _as_given(early, start, kept_source, tree, limit, options, refine)
    else:
        # 2. The learned side: both masks once, then masked matches and rotations.
        if predict_masks is not None:
            mask, source_mask = predict_masks(template, source)
            if (source_mask & surface).sum() >= MIN_POINTS:
                kept_source = source[source_mask & surface]
            else:
                source_mask = np.ones(len(source), bool)
            tic = clock("mask", tic)
            for grid in grids:  # the matches that touch no rejected point, again
                keep_s = _voxel_labels(grid[0].points, source, source_mask)
                keep_t = _voxel_labels(grid[1].points, template, mask)
                masked = grid[2][keep_s[grid[2][:, 0]] & keep_t[grid[2][:, 1]]]
                if len(masked) >= MIN_POINTS:
                    correspondence_poses(grid, masked, "fpfh-masked", probe)
                tic = clock("ransac", tic)
        # Every hypothesis through a short ICP at hypothesis resolution (the
        # correspondence poses against the whole template, the rotations against the
        # masked part), then scored on the same kept points.
        points = random_subset(kept_source, small * 2)
        src_small = random_subset(kept_source, small)
        whole_small = random_subset(template, small)
        if scored:
            poses = icp_from_starts(
                cloud_tree(whole_small),
                whole_small,
                src_small,
                np.stack([s.pose for s in scored]),
                options.max_iterations,
            )
            # Both as found and after the short ICP: on a large scene the ICP at
            # hypothesis resolution can move a good pose off.
            both = np.concatenate([np.stack([s.pose for s in scored]), poses])
            kinds = [s.kind for s in scored] * 2
            fits = pose_fits(tree, points, both, limit)
            scored[:] = [Scored(*f, p, k) for f, p, k in zip(fits, both, kinds, strict=True)]
        # The clouds as they are: consecutive scans often start close.
        as_given = _short_icp_from_identity(template, kept_source, small, options.max_iterations)
        both = np.stack([np.eye(4), as_given])
        fits = pose_fits(tree, points, both, limit)
        scored.extend(Scored(*f, p, "as given") for f, p in zip(fits, both, strict=True))
        target = template if mask is None or mask.sum() < MIN_POINTS else template[mask]
        target_small = random_subset(target, small)
        src_centre, tgt_centre = src_small.mean(0), target.mean(0)
        rotations = hypothesis_rotations(24)[: options.hypotheses]
        if len(rotations):
            starts = np.tile(np.eye(4), (len(rotations), 1, 1))
            starts[:, :3, :3] = rotations
            starts[:, :3, 3] = tgt_centre - rotations @ src_centre
            poses = icp_from_starts(
                cloud_tree(target_small), target_small, src_small, starts, options.max_iterations
            )
            fits = pose_fits(tree, points, poses, limit)
            scored.extend(Scored(*f, p, "rotation") for f, p in zip(fits, poses, strict=True))
        tic = clock("hypotheses", tic)
        # 3. The best few, refined with the pair cut-off, rescored on all kept points.
        scored.sort(key=_rank, reverse=True)
        # Candidates from different basins (CANDIDATE_BASIN): close poses refine into one.
        best_few = _distinct(
            scored, options.candidates, CANDIDATE_BASIN * radius, options.distinct_deg
        )
        finals = [refine(s.pose, kept_source, s.kind) for s in best_few]
        tic = clock("refine", tic)
    if not finals:  # no hypothesis at all (too few points for features): the identity
        finals = [Scored(*pose_fit(tree, kept_source, np.eye(4), limit), np.eye(4), "identity")]
    # Refined answers that met in one basin are one answer: only different poses that fit
    # alike make the choice below (and its re-refinement) necessary.
    finals = _distinct(sorted(finals, key=_rank, reverse=True), len(finals), limit)
    # Among answers that fit alike (within the margin), the least rotation from the pose
    # as given wins: the data cannot choose, and the input is the only other evidence. The
    # result says so (ambiguous, with the runner-up).
    alike = [f for f in finals if f.score >= finals[0].score - options.ambiguity_margin]
    if len(alike) > 1:
        # Before the input decides, the fits each answer reaches when refined as far as
        # it goes (a looser cut-off first) rank them; the answers keep their poses and
        # their own fits, as a looser cut-off can also move a right pose on a partial scan.
        reached = {id(f): refine(f.pose, kept_source, f.kind, loose=True).score for f in finals}
        finals.sort(key=lambda f: reached[id(f)], reverse=True)
        top = reached[id(finals[0])]
        alike = [f for f in finals if reached[id(f)] >= top - options.ambiguity_margin]
    else:
        reached = {id(f): f.score for f in finals}
    winner = min(alike, key=lambda f: rotation_between_deg(f.pose, np.eye(4)))
    rival = next(
        (
            f
            for f in finals
            if f is not winner and rotation_between_deg(f.pose, winner.pose) >= options.distinct_deg
        ),
        None,
    )
    ambiguous = (
        rival is not None and reached[id(rival)] >= reached[id(winner)] - options.ambiguity_margin
    )
    transform = winner.pose
    if predict_masks is not None:  # the template points the moved kept source covers
        # (also after an early exit, where the network never ran)
        moved = transform_points(transform, kept_source)
        mask = cloud_tree(moved).query(full_template, k=1)[0] <= limit
    if source_mask is not None and len(source) < len(full_source):
        # Each point of the whole source takes the label of its nearest subset point.
        source_mask = spread_labels(full_source, source, source_mask)
    info = {
        "path": "correspondences" if early is not None else "search",
        "source": winner.kind,
        "fitness": winner.fitness,
        "inlier_rmse": winner.rmse,
        "score": winner.score,
        "ambiguous": bool(ambiguous),
        "runner_up": None if rival is None else rival.pose,
        "runner_up_fitness": float("nan") if rival is None else rival.fitness,
        "runner_up_score": float("nan") if rival is None else rival.score,
        "hypotheses": len(scored),
    }
    return CoarseRun(transform, mask, source_mask, info)


class Scored(NamedTuple):
    """A hypothesis: its fit (:class:`PoseFit`), pose (4, 4), and where it came from."""

    fitness: float
    rmse: float
    score: float
    pose: np.ndarray
    kind: str


def _rank(entry: Scored) -> tuple[float, float, float]:
    """Higher score first, then fitness, then lower RMSE."""
    return entry.score, entry.fitness, -entry.rmse


def _has_open3d() -> bool:
    """Whether Open3D imports (it may be installed and still fail, e.g. without libusb)."""
    from masknet.errors import MaskNetError
    from masknet.io import require_open3d

    try:
        require_open3d("FPFH features")
    except MaskNetError:
        return False
    return True


def _voxel_labels(voxels: np.ndarray, points: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """(V,) bool: whether the input point nearest each voxel centre (V, 3) is kept."""
    return spread_labels(voxels, points, keep)


def _short_icp_from_identity(
    template: np.ndarray, source: np.ndarray, points: int, iterations: int
) -> np.ndarray:
    """(4, 4): ``iterations`` of ICP from the identity on at most ``points`` of each cloud
    (template (N, 3), source (M, 3)): the clouds as they are, at hypothesis resolution."""
    src_small = random_subset(source, points)
    whole_small = random_subset(template, points)
    return icp_from_starts(
        cloud_tree(whole_small), whole_small, src_small, np.eye(4)[None], iterations
    )[0]


def _as_given(
    early: list[Scored],
    start: np.ndarray,
    kept_source: np.ndarray,
    tree: Any,
    limit: float,
    options: RobustOptions,
    refine: Callable[[np.ndarray, np.ndarray, str], Scored],
) -> list[Scored]:
    """The clouds as they are (``start``, their short ICP from the identity), refined: one
    more answer beside the early exit's where it fits better than they do. A symmetric
    shape's flip can pass the early exit (a noisy ModelNet40 pair: the flip fit 0.992 of
    its points, the truth 1.0; scores 0.967 and 0.990), and only an answer found can be
    weighed against it. Not refined when ``start`` lies in an early answer's basin or fits
    ``AS_GIVEN_GAP`` below the best (it seldom climbs that far); not kept when it fits no
    better, since a nearby local fit within the ambiguity margin would otherwise win as
    the least rotation (with noise sigma 0.02, a mean of 2.84 degrees instead of 2.31)."""
    if any(rotation_between_deg(start, e.pose) < options.distinct_deg for e in early):
        return []  # the early exit's own basin
    best = max(e.score for e in early)
    if pose_fit(tree, kept_source, start, limit).score < best - AS_GIVEN_GAP:
        return []
    found = refine(start, kept_source, "as given")
    return [found] if found.score > best else []


def _distinct(scored: list, count: int, limit: float, degrees: float = 2.0) -> list:
    """The first ``count`` entries of ``scored`` (best first) whose poses differ from every
    earlier one kept by ``degrees`` or ``limit`` of translation: the same basin once."""
    out: list = []
    for entry in scored:
        if len(out) == count:
            break
        if all(
            rotation_between_deg(entry.pose, other.pose) >= degrees
            or np.linalg.norm(entry.pose[:3, 3] - other.pose[:3, 3]) >= limit
            for other in out
        ):
            out.append(entry)
    return out
