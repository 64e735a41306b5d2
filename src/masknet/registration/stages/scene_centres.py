"""Where the scene search places the template: candidate centres, and which of them to try.

:func:`candidate_centres` puts one centre in every occupied cell of a grid over the thinned
scene, where the scene holds enough points around it. :func:`likely_centres` keeps the
share of them whose surroundings look most like the template: FPFH features
(:func:`masknet.registration.solvers.correspondences.feature_cloud`, on a grid of
``feature_voxel`` template radii) of the scene and the template; the scene points whose
nearest template feature is among the closest tenth (``LIKE_SHARE``) look like the
object, and a centre scores the fraction of such points within about one template radius. The
features do not depend on the rotation, so one ranking serves all of a centre's
rotations, and every stage after it runs on fewer placements.

All lengths are in template radii (the scene search's frame).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from masknet.errors import MaskNetError
from masknet.geometry.knn import cloud_tree
from masknet.geometry.sampling import first_in_cells
from masknet.io import has_open3d
from masknet.registration.terms.options import SceneSearch

__all__ = ["candidate_centres", "likely_centres", "voxel_thin"]

LIKE_SHARE = 0.1  # scene points whose features are among this share closest to the template's
FEATURE_REACH = 1.0  # radius around a centre whose points score it: the object's own
MIN_CENTRES = 128  # at least this many centres are kept (a small scene is searched whole)
NEIGHBOUR_CENTRES = 64  # centres within FEATURE_REACH summed (about 33 on the default grid)


def voxel_thin(points: np.ndarray, size: float) -> np.ndarray:
    """One point per occupied voxel of edge ``size`` (the first in input order): (K, 3)."""
    return points[np.sort(first_in_cells(points, size, origin=np.zeros(3)))]


def candidate_centres(
    thin: np.ndarray, thin_tree: Any, opts: SceneSearch
) -> tuple[np.ndarray, float]:
    """Centres (C, 3) on a grid over the thinned scene (T, 3) with enough scene around
    them, and the grid's spacing (coarser than asked for a scene too large for the
    budget, and then searched less reliably)."""
    spacing = opts.spacing
    centres = voxel_thin(thin, spacing)
    while len(centres) * opts.hypotheses > opts.max_placements:
        spacing *= 1.25
        centres = voxel_thin(thin, spacing)
    # A region is large enough when its min_region_points-th nearest point lies within it.
    need = min(opts.min_region_points, len(thin))
    kth, _ = thin_tree.query(centres.astype(np.float32), k=need, distance_upper_bound=opts.crop)
    enough = np.isfinite(np.asarray(kth).reshape(len(centres), need)[:, -1])
    centres = centres[enough if need >= opts.min_region_points else np.zeros(len(centres), bool)]
    if not len(centres):
        raise MaskNetError(
            f"scene search: no region of the scene holds {opts.min_region_points} points "
            f"within {opts.crop} template radii"
        )
    return centres, spacing


def centre_scores(
    tpl: np.ndarray, thin: np.ndarray, centres: np.ndarray, voxel: float
) -> np.ndarray:
    """(C,) for ``centres`` (C, 3): the fraction of the thinned scene's (T, 3) feature points
    around each whose FPFH lies among the ``LIKE_SHARE`` closest to the template's (N, 3)
    (module docstring); 0 where none is near. Each feature point counts for its nearest
    centre, and a centre sums the counts of the centres within ``FEATURE_REACH`` of it
    (its own included, at most ``NEIGHBOUR_CENTRES``): the points within about that reach."""
    from masknet.registration.solvers.correspondences import feature_cloud

    template, scene = feature_cloud(tpl, voxel), feature_cloud(thin, voxel)
    if not len(template.points) or not len(scene.points):
        return np.zeros(len(centres))
    gap, _ = cloud_tree(template.features).query(scene.features, k=1)
    alike = gap <= np.quantile(gap, LIKE_SHARE)
    centre_tree = cloud_tree(centres)
    _, owner = centre_tree.query(scene.points, k=1)
    hits = np.bincount(owner, weights=alike, minlength=len(centres))
    total = np.bincount(owner, minlength=len(centres)).astype(np.float64)
    k = min(len(centres), NEIGHBOUR_CENTRES)
    _, around = centre_tree.query(centres, k=k, distance_upper_bound=FEATURE_REACH)
    around = np.asarray(around).reshape(len(centres), k)
    inside = around < len(centres)  # a missing neighbour has index len(centres)
    index = np.where(inside, around, 0)
    near_hits = np.where(inside, hits[index], 0.0).sum(1)
    near_total = np.where(inside, total[index], 0.0).sum(1)
    return near_hits / np.maximum(near_total, 1)


def likely_centres(
    tpl: np.ndarray, thin: np.ndarray, centres: np.ndarray, opts: SceneSearch
) -> np.ndarray:
    """The ``opts.centre_share`` of ``centres`` (C, 3) whose surroundings in the thinned
    scene (T, 3) look most like the template (N, 3) (:func:`centre_scores`), at least
    ``MIN_CENTRES``; all of them where the share is 1 or Open3D is not installed."""
    keep = max(math.ceil(opts.centre_share * len(centres)), MIN_CENTRES)
    if keep >= len(centres) or not has_open3d():
        return centres
    scores = centre_scores(tpl, thin, centres, opts.feature_voxel)
    return centres[np.argsort(-scores, kind="stable")[:keep]]
