"""Finding an object in a scene: the template is a small object, the source a large scan.

When the object covers a few per cent of the scan, neither MaskNet (trained on pairs
where the source is mostly the template's object) nor ICP from the scene's centroid
can find it: the scene's centroid is metres away and almost every source point is
clutter. :func:`locate` searches instead:

1. Frame: everything is measured in template radii
   (:func:`~masknet.geometry.clouds.unit_radius`, about the bounding-box centre) from the
   template's centroid, so the result does not depend on the unit. The scene is thinned on a voxel grid of
   ``voxel`` radii.
2. Candidate centres: one scene point per occupied cell of a grid of ``spacing`` radii
   (every scene point lies within ``1.73 * spacing`` of one), kept where the scene holds
   ``min_region_points`` points within ``crop`` radii of it; of those, the
   ``centre_share`` whose surroundings look most like the template by FPFH features (at
   least 128; :mod:`masknet.registration.stages.scene_centres`).
3. Hypotheses: the template, thinned to ``hypothesis_points``, is placed at every kept
   centre in each of the 24 rotations of the cube, and every placement runs trimmed ICP *of the
   template onto the thinned scene* (each template point finds its nearest scene point,
   and the best ``trim`` of the pairs move it: the object explains itself, the clutter
   need not be explained), all placements at once. After 2, 5 and 10 iterations (and
   every 5 after) the worst three quarters are dropped, and (without a viewpoint) the
   points used grow as the placements shrink: at the default 64, 16 until the second
   drop, 32 until the third, then all. Where there are ``FIELD_FROM`` placements or more
   (every centre searched), in the two iterations before the first drop each template
   point's scene point is looked up (without a viewpoint) in a voxel field of the scene's
   nearest points (:class:`~masknet.geometry.knn.NearestField`, cells of 0.125 radii)
   instead of searched in the KD-tree; the drop itself ranks the placements on the tree's
   exact matches.
4. Scoring: the trimmed mean squared distance of the moved template points to the
   scene (the best ``trim`` fraction): low where the object lies on scene points.
5. Refinement: the ``candidates`` best placements run ICP again at ``refine_points``
   template points against the scene around them, with correspondences cut at
   ``refine_distance`` radii: 5 iterations each, then the best quarter by the trimmed fit
   the rest. The best runs a last ICP against the full-resolution scene.

The result maps **scene points into the template frame** (masknet's convention,
``template ~= source @ R.T + t``). The source mask marks the scene points within the
inlier distance of the moved template: ``inlier_distance`` radii, or 1.5 template point
spacings for a sparser template (at most ``refine_distance``).

The template should be the object as the scan sees it (a view captured by a sensor, as
a scanned model is): the score asks every template point to lie on the scan, so a full
360-degree model against a one-sided view is found less often.

Cost, 2 CPU threads: about 0.7 s of a 0.9-1.2 s call for a 12,000-point object in a
240,000-point scene ten times its size; it grows with the centres kept (an eighth of the
scene's area in template radii, at least 128), up to ``max_placements`` (then the centre
grid is made coarser).

Example::

    found = locate(carton, kinect_scene)
    found.transform        # (4, 4) scene -> carton
    found.source_mask      # (P,) bool: the scene points on the carton
"""

from __future__ import annotations

import time
from typing import Any, NamedTuple

import numpy as np
import torch

from masknet.geometry.align import rigid_transforms_numpy
from masknet.geometry.clouds import (
    MIN_POINTS,
    centroid_radius,
    median_spacing,
    median_spread,
    unit_radius,
)
from masknet.geometry.knn import NearestField, cloud_tree, nearest_field_cells
from masknet.geometry.normals import estimate_normals
from masknet.geometry.sampling import farthest_point_sample, grid_subset
from masknet.geometry.se3 import hypothesis_rotations, transform_points
from masknet.geometry.trimmed import trimmed_fit, trimmed_mean, trimmed_order
from masknet.registration.judge import arbiter
from masknet.registration.solvers.icp import icp
from masknet.registration.stages.scene_centres import candidate_centres, likely_centres, voxel_thin
from masknet.registration.terms.options import SceneSearch, inlier_cutoff

__all__ = ["SceneSearch", "SceneMatch", "is_scene", "locate", "polish"]

# Hypothesis-stage iterations at which the worst three quarters of the placements are
# dropped (and every PRUNE_EVERY after the last). Dropping every 5 iterations from the
# start ran 5 iterations of every placement first, most of the search: on the carton's
# scene the search took 4.3 s before and 1.9 s after, the same pose (docs/RESULTS.md,
# the carton).
PRUNE_AT = (2, 5, 10)
PRUNE_EVERY = 5
# Before the first drop every placement runs, and the nearest scene point of each template
# point is looked up in a NearestField of cells FIELD_CELL template radii wide instead of
# searched in the KD-tree (a placement starts up to 0.43 radii from the object, so its first
# steps need no finer match). The drop ranks on the tree: ranked on the field too, the
# synthetic scenes' full model was found in 9 of 20 instead of 10, 0.1 s sooner. On the
# carton's scene, alternating in one run, the whole call took 0.73 times as long with the
# field and the halved refinement below, the same pose (docs/RESULTS.md, the carton).
# FIELD_MAX_CELLS bounds its memory (4 bytes a cell kept, about 30 while it is built); a
# scene too large for it in cells of at most FIELD_CELL_MAX radii searches the tree
# throughout. Building it costs about what the tree's queries of FIELD_FROM placements'
# first iterations do (0.1-0.15 s on the carton's scene), so fewer placements skip it.
FIELD_CELL = 0.125
FIELD_CELL_MAX = 0.3
FIELD_MAX_CELLS = 8_000_000
FIELD_UNTIL = PRUNE_AT[0] - 1  # the last iteration that looks up the field
FIELD_FROM = 8_000  # placements (centres x rotations) from which the field is built
# Refinement iterations of every candidate before the best quarter go on: 16 candidates
# of 30 iterations each took 0.45 s of the carton's search, halved 0.20 s.
REFINE_FIRST = 5
MIN_FACING = 0.2  # with a viewpoint: a placement showing the sensor fewer points is out


class SceneMatch(NamedTuple):
    """What :func:`locate` finds.

    transform: (4, 4) scene -> template. source_mask: (P,) bool, the scene points on the
    object. coverage: fraction of template points (those facing the sensor, with a
    viewpoint) within the inlier distance of the scene at the found pose (a share of the
    template, unlike ``fitness`` elsewhere, which counts source points). inlier_rmse: RMS distance of those points, in the input's units.
    regions: candidate regions searched. hypotheses: placements run in the batched stage.
    seconds: the search's time. spacing: the centre grid used, in template radii (the
    option's, or coarser where the scene exceeded ``max_placements``).
    """

    transform: np.ndarray
    source_mask: np.ndarray
    coverage: float
    inlier_rmse: float
    regions: int
    hypotheses: int
    seconds: float
    spacing: float


def is_scene(template: np.ndarray, source: np.ndarray, options: SceneSearch | None = None) -> bool:
    """Whether ``source`` (M, 3) is at least ``scene_ratio`` times as spread out as
    ``template`` (N, 3) (:class:`SceneSearch`): an object to find in a scene, not a view
    of the object, with or without outliers."""
    ratio = (options or SceneSearch()).scene_ratio
    spread = median_spread(template)
    return spread > 0 and median_spread(source) >= ratio * spread


def _inlier_distance(unit_template: np.ndarray, options: SceneSearch) -> float:
    """The inlier distance in template radii for a unit-radius template (N, 3): the
    option, or 1.5 median nearest-neighbour spacings of the template if more, but never
    more than ``refine_distance`` (a template of a few points has huge spacings)."""
    spacing = median_spacing(unit_template)
    return max(options.inlier_distance, min(inlier_cutoff(spacing), options.refine_distance))


def _nearest(
    poses: np.ndarray, points: np.ndarray, cloud: np.ndarray, tree: object
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``points`` (P, 3) moved by each of ``poses`` (B, 4, 4): the moved points (B, P, 3),
    their nearest points of ``cloud`` (found by ``tree``: a float32 KD-tree or a
    :class:`NearestField`) (B, P, 3), and the squared distances (B, P)."""
    moved = transform_points(poses, points[None])
    _, idx = tree.query(moved.reshape(-1, 3).astype(np.float32), k=1)
    matched = cloud[idx.astype(np.int64)].reshape(moved.shape)
    return moved, matched, ((moved - matched) ** 2).sum(-1)


def _outward_normals(points: np.ndarray) -> np.ndarray:
    """PCA normals (N, 3) of a cloud (N, 3), each turned away from the cloud's centroid: a
    point faces the sensor where its outward normal points towards it (:func:`_facing`).
    The FPFH features' normals turn the other way, towards the centroid, where only their
    sign's consistency matters (:func:`masknet.registration.solvers.correspondences.fpfh_features`)."""
    normals = estimate_normals(torch.from_numpy(points[None]))[0][0].numpy()
    flip = np.einsum("ij,ij->i", normals, points - points.mean(0)) < 0
    return np.where(flip[:, None], -normals, normals)


def _facing(
    poses: np.ndarray, moved: np.ndarray, normals: np.ndarray | None, sensor: np.ndarray | None
) -> np.ndarray | None:
    """(B, P) bool: which template points, moved by each of ``poses`` (B, 4, 4) to ``moved``
    (B, P, 3), face ``sensor`` (3,) (their normals (P, 3) turn towards it); None without a
    sensor (every point counts)."""
    if sensor is None:
        return None
    turned = np.einsum("bij,pj->bpi", poses[:, :3, :3], normals)
    return np.einsum("bpi,bpi->bp", turned, sensor - moved) > 0


def _scores(d2: np.ndarray, facing: np.ndarray | None, trim: float) -> np.ndarray:
    """Trimmed fit (B,) of each placement's squared distances (B, P), over the points that
    face the sensor; inf where under ``MIN_FACING`` of them do."""
    scores = trimmed_mean(d2, trim, facing)
    if facing is not None:
        scores[facing.sum(1) < MIN_FACING * d2.shape[1]] = np.inf
    return scores


def _trim_weights(d2: np.ndarray, facing: np.ndarray | None, trim: float) -> np.ndarray:
    """(B, P) float64 weights of trimmed ICP: 1 for the best ``trim`` of each placement's
    pairs (among the points facing the sensor), else 0."""
    valid = np.ones(d2.shape, bool) if facing is None else facing
    ordered, keep = trimmed_order(d2, trim, valid, min_keep=MIN_POINTS)
    cut = ordered[np.arange(len(d2)), np.minimum(keep, d2.shape[1]) - 1]
    return (valid & (d2 <= cut[:, None])).astype(np.float64)


def _seen(
    pose: np.ndarray, points: np.ndarray, normals: np.ndarray | None, sensor: np.ndarray | None
) -> np.ndarray:
    """(P,) bool: the template points facing the sensor at ``pose`` (all without one, or
    where fewer than 3 would)."""
    facing = _facing(pose[None], transform_points(pose, points)[None], normals, sensor)
    if facing is None or facing[0].sum() < MIN_POINTS:
        return np.ones(len(points), bool)
    return facing[0]


def locate(
    template: np.ndarray, scene: np.ndarray, options: SceneSearch | None = None
) -> SceneMatch:
    """Find the object ``template`` (N, 3) in ``scene`` (P, 3), any units (module docstring).

    Raises:
        MaskNetError: bad options, or no region of the scene large enough to search.
    """
    tic = time.perf_counter()
    opts = options or SceneSearch()
    opts.check()
    template = np.asarray(template, dtype=np.float64)
    scene = np.asarray(scene, dtype=np.float64)
    centre = template.mean(0)
    radius = float(unit_radius(template))
    tpl = (template - centre) / radius  # template frame, unit radius
    scn = (scene - centre) / radius
    # 1-2. Thinned scene and candidate centres (those with enough scene around them).
    thin = voxel_thin(scn, opts.voxel)
    # Nearest neighbours in the hot loop, in float32 (the refinement is float64).
    thin_tree = cloud_tree(thin, np.float32)
    centres, spacing = candidate_centres(thin, thin_tree, opts)
    centres = likely_centres(tpl, thin, centres, opts)
    sensor = None if opts.viewpoint is None else (np.asarray(opts.viewpoint) - centre) / radius
    normals = None if sensor is None else _outward_normals(tpl)
    # 3-4. Every rotation at every centre, the best few kept.
    placed = _Placement(tpl, normals, sensor, opts)
    # With a viewpoint the tree serves throughout: the carton, the Kinect's position given,
    # was lost (130 degrees off) when even the first iteration looked up the field.
    many = len(centres) * opts.hypotheses >= FIELD_FROM
    field = _coarse_field(thin) if sensor is None and many else None
    poses, count = placed.search(centres, thin, thin_tree, field)
    # 5. The best placements at finer resolution against the thinned scene, rescored.
    pose = placed.best_refined(poses, thin)
    # Last: the full template against the full-resolution scene around the object.
    tolerance = _inlier_distance(tpl, opts)
    around = scn[np.linalg.norm(scn - pose[:3, 3], axis=1) <= 1.0 + opts.refine_distance]
    seen = _seen(pose, tpl, normals, sensor)
    if len(around) >= MIN_POINTS:
        pose = icp(
            around,
            tpl[seen],
            pose,
            max_iterations=2 * opts.max_iterations,
            max_correspondence_distance=tolerance,
        ).transform[0]
    moved_tpl = transform_points(pose, tpl[_seen(pose, tpl, normals, sensor)])
    # Only scene points within the template's reach (plus the tolerance) of its centre can
    # lie within the tolerance of it: the fit and the mask need no tree of the whole scene.
    reach = float(centroid_radius(tpl)) + tolerance
    nearby = np.flatnonzero(np.linalg.norm(scn - pose[:3, 3], axis=1) <= reach)
    dist = np.full(len(moved_tpl), np.inf)
    source_mask = np.zeros(len(scn), bool)  # (P,) bool: scene points on the moved template
    if len(nearby):
        dist, _ = cloud_tree(scn[nearby]).query(moved_tpl, k=1)
        near = cloud_tree(moved_tpl).query(scn[nearby], k=1, distance_upper_bound=tolerance)
        source_mask[nearby] = np.isfinite(near[0])
    close = dist <= tolerance
    coverage = float(close.mean())
    rmse = float(np.sqrt(np.square(dist[close]).mean())) * radius if close.any() else 0.0
    # pose maps unit-frame template -> unit-frame scene; invert and leave the unit frame:
    # template = centre + radius * tpl, scene = centre + radius * scn.
    inverse = np.linalg.inv(pose)
    transform = np.eye(4)
    transform[:3, :3] = inverse[:3, :3]
    transform[:3, 3] = centre + radius * inverse[:3, 3] - inverse[:3, :3] @ centre
    seconds = time.perf_counter() - tic
    return SceneMatch(transform, source_mask, coverage, rmse, len(centres), count, seconds, spacing)


def _coarse_field(thin: np.ndarray) -> NearestField | None:
    """The :class:`NearestField` of the thinned scene (T, 3) for the search's first
    iterations (cells of :data:`FIELD_CELL` radii, coarser for a large scene), or None
    where even :data:`FIELD_CELL_MAX` would exceed :data:`FIELD_MAX_CELLS` cells."""
    # Most of a placed template lies within 1 radius of its centre (the radius is measured
    # from the bounding box's centre, so a point may reach further: it takes the boundary).
    cell, margin = FIELD_CELL, 1.0
    while nearest_field_cells(thin, cell, margin) > FIELD_MAX_CELLS:
        cell *= 1.25
        if cell > FIELD_CELL_MAX:
            return None
    return NearestField(thin, cell, margin)


def _drops(iteration: int) -> bool:
    """Whether the worst three quarters of the placements are dropped at ``iteration``."""
    last = PRUNE_AT[-1]
    return iteration in PRUNE_AT or (iteration > last and (iteration - last) % PRUNE_EVERY == 0)


def _points_at(iteration: int, points: int) -> int:
    """Template points in the placements' trimmed ICP at ``iteration`` of ``points``: an
    eighth (at least 16) until the first drop of placements, doubling at each of the next
    three. At the default 64 points: 16 until the second drop, then 32, then 64."""
    drops = sum(iteration >= at for at in PRUNE_AT)
    return min(points, max(points // (8 >> min(drops, 3)), 16))


class _Placement:
    """The template (unit frame, (N, 3)), its outward normals (N, 3) and the sensor (3,) (both
    None without a viewpoint), for placing it in a scene."""

    def __init__(
        self,
        tpl: np.ndarray,
        normals: np.ndarray | None,
        sensor: np.ndarray | None,
        opts: SceneSearch,
    ) -> None:
        self.tpl, self.normals, self.sensor, self.opts = tpl, normals, sensor, opts
        # The placements' few points spread by farthest-point sampling; the refinement's
        # many an even grid subset (farthest points to 1,024 of the carton's 12,575 cost
        # 50 ms, the grid 6).
        self.small = farthest_point_sample(tpl, opts.hypothesis_points).indices
        self.fine = grid_subset(tpl, opts.refine_points)

    def search(
        self,
        centres: np.ndarray,
        thin: np.ndarray,
        thin_tree: Any,
        field: NearestField | None = None,
    ) -> tuple[np.ndarray, int]:
        """Every rotation at every centre (C, 3): trimmed ICP of the template onto the thinned
        scene (T, 3), all placements at once against one KD-tree (``field``, where given,
        in the iterations before the first drop). The best ``candidates`` poses (K, 4, 4),
        template -> scene, best first, and how many placements started."""
        opts, sensor = self.opts, self.sensor
        pick = self.small
        small = self.tpl[pick]
        small_normals = None if self.normals is None else self.normals[pick]
        rotations = hypothesis_rotations(opts.hypotheses)
        count = len(centres) * len(rotations)
        poses = np.tile(np.eye(4), (count, 1, 1))  # template -> scene
        poses[:, :3, :3] = np.tile(rotations, (len(centres), 1, 1))
        poses[:, :3, 3] = np.repeat(centres, len(rotations), axis=0)
        for iteration in range(opts.max_iterations):
            # Points grow as placements shrink (_points_at; the first k of a farthest-
            # point order are themselves spread over the template). Not with a sensor:
            # the facing test leaves too few of a quarter (the carton, the Kinect's
            # position given, was found 111 degrees off).
            used = len(small) if sensor is not None else _points_at(iteration, len(small))
            points = small[:used]
            normals = None if small_normals is None else small_normals[:used]
            index = field if field is not None and iteration <= FIELD_UNTIL else thin_tree
            moved, matched, d2 = _nearest(poses, points, thin, index)
            facing = _facing(poses, moved, normals, sensor)
            if _drops(iteration):
                # Placements that fit worst are dropped as they go: the right one fits early.
                keep = arbiter.lowest_quarter(_scores(d2, facing, opts.trim), opts.candidates)
                poses, moved, matched, d2 = poses[keep], moved[keep], matched[keep], d2[keep]
                facing = None if facing is None else facing[keep]
            # Trimmed ICP: only the best ``trim`` of each placement's pairs move it, so the
            # template's parts that the scan does not see do not pull it.
            weights = _trim_weights(d2, facing, opts.trim)
            poses = rigid_transforms_numpy(moved, matched, weights) @ poses
        # Trimmed fit of every placement: the best few go on.
        moved, _, d2 = _nearest(poses, small, thin, thin_tree)
        scores = _scores(d2, _facing(poses, moved, small_normals, sensor), opts.trim)
        return poses[arbiter.lowest(scores, opts.candidates)], count

    def best_refined(self, poses: np.ndarray, thin: np.ndarray) -> np.ndarray:
        """(4, 4): the best of ``poses`` (K, 4, 4) after ICP at finer resolution against the
        thinned scene (T, 3) around each, by their trimmed fit. Halving, as in the search:
        every pose takes :data:`REFINE_FIRST` iterations (per pass: two with a viewpoint),
        and the best quarter by fit the rest of ``2 * max_iterations``, cropped again
        around where the first iterations left them."""
        opts = self.opts
        pick = self.fine
        fine = self.tpl[pick]
        fine_normals = None if self.normals is None else self.normals[pick]
        total = 2 * opts.max_iterations
        first = [
            self._refined(pose, fine, fine_normals, thin, min(REFINE_FIRST, total))
            for pose in poses
        ]
        first = arbiter.least_first(first)
        if total > REFINE_FIRST:
            first = [
                self._refined(pose, fine, fine_normals, thin, total - REFINE_FIRST)
                for _, pose in arbiter.best_quarter(first)
            ]
        return arbiter.least_trimmed(first)

    def _refined(
        self,
        pose: np.ndarray,
        fine: np.ndarray,
        fine_normals: np.ndarray | None,
        thin: np.ndarray,
        iterations: int,
    ) -> tuple[float, np.ndarray]:
        """ICP of the template points ``fine`` (F, 3) (outward normals (F, 3) with a
        viewpoint) from ``pose`` (4, 4) onto the thinned scene (T, 3) around it, at most
        ``iterations`` per pass: (trimmed fit, inf where too few points face the sensor;
        the pose)."""
        opts = self.opts
        around = thin[np.linalg.norm(thin - pose[:3, 3], axis=1) <= opts.crop + 1.0]
        for _ in range(1 if self.sensor is None else 2):  # the side facing the sensor moves
            seen = _seen(pose, fine, fine_normals, self.sensor)
            run = icp(
                around,
                fine[seen],
                pose,
                max_iterations=iterations,
                max_correspondence_distance=opts.refine_distance,
            )
            pose = run.transform[0]
        seen = _seen(pose, fine, fine_normals, self.sensor)
        fit = trimmed_fit(transform_points(pose, fine[seen])[None], around[None], opts.trim)[0]
        return (fit if seen.mean() >= MIN_FACING else np.inf), pose


def polish(
    template: np.ndarray,
    points: np.ndarray,
    starts: list[np.ndarray],
    options: SceneSearch | None = None,
) -> np.ndarray:
    """The last step after a scene search: ICP of the object's scene points (P, 3) onto the
    whole template (N, 3) at full resolution from each of ``starts`` ((4, 4) each, scene ->
    template), pairs cut at the inlier distance (:class:`SceneSearch`); the result whose
    points lie closest to the template (trimmed fit) wins. Returns it, (4, 4).

    The method that runs between search and polish works on sampled clouds and may drift
    by about a sample spacing; the search's own pose is one of the starts, so the call
    never ends farther from the object than the search did.
    """
    opts = options or SceneSearch()
    template = np.asarray(template, np.float64)
    points = np.asarray(points, np.float64)
    radius = float(unit_radius(template))
    cut = radius * _inlier_distance((template - template.mean(0)) / radius, opts)
    refined = []
    for start in starts:
        run = icp(
            template,
            points,
            start,
            max_iterations=2 * opts.max_iterations,
            max_correspondence_distance=cut,
        )
        pose = run.transform[0]
        fit = trimmed_fit(transform_points(pose, points)[None], template[None], opts.trim)[0]
        refined.append((fit, pose))
    return arbiter.polished(refined, starts[0])
