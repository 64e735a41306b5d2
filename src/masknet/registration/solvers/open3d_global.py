"""Open3D's global registration on FPFH features: RANSAC and Fast Global Registration.

The classical peers a user would reach for instead of a learned method. Both run
on one pair; the feature radii scale with ``voxel_size`` (in the clouds' units),
as in Open3D's global-registration tutorial: normals within 2 voxels, FPFH within 5,
RANSAC inlier distance 1.5 voxels, FGR correspondence distance 0.5 voxels. The
returned transform maps the source onto the template (masknet's convention).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from masknet._open3d import open3d_threads
from masknet.geometry.open3d_clouds import to_open3d
from masknet.io import require_open3d
from masknet.registration.solvers.correspondences import fpfh_features

__all__ = [
    "RANSAC_INLIER_VOXELS",
    "TUTORIAL_NEIGHBOURS",
    "open3d_fgr",
    "open3d_fpfh_ransac",
    "ransac_on_features",
    "ransac_on_matches",
]

TUTORIAL_NEIGHBOURS = 100  # FPFH neighbours within 5 voxels, as the tutorial takes them
RANSAC_INLIER_VOXELS = 1.5  # RANSAC's inlier distance, in voxels, as the tutorial sets it


def _cloud_and_features(
    o3d, points: np.ndarray, voxel_size: float, downsample: bool = False, orient: bool = False
):
    cloud = to_open3d(points)
    if downsample:  # the tutorial's first step, for clouds denser than the voxel
        cloud = cloud.voxel_down_sample(voxel_size)
    return cloud, fpfh_features(o3d, cloud, voxel_size, TUTORIAL_NEIGHBOURS, orient)


def open3d_fpfh_ransac(
    template: np.ndarray,
    source: np.ndarray,
    voxel_size: float = 0.05,
    max_iterations: int = 100_000,
    confidence: float = 0.999,
    seed: int = 0,
    repeatable: bool = True,
    downsample: bool = False,
    orient_normals: bool = False,
) -> tuple[np.ndarray, float, float]:
    """RANSAC on FPFH matches (Open3D); returns (transform (4, 4), fitness, inlier_rmse).

    Arguments in masknet's order: template (N, 3), then source (M, 3), the points to move.
    ``seed`` fixes Open3D's random generator. Open3D runs RANSAC's trials in parallel
    threads with an early stop, so even seeded runs can differ (Open3D issue 7475);
    ``repeatable=True`` (the default) runs it on one thread, which makes the same input
    and seed give the same transform (docs/RESULTS.md gives the cost). ``downsample``:
    reduce both clouds to the voxel grid first, as Open3D's tutorial does for dense scans.
    ``orient_normals``: turn each cloud's normals towards its centroid before the features
    (:func:`~masknet.registration.solvers.correspondences.fpfh_features`; the tutorial does not).
    """
    o3d = require_open3d("Open3D RANSAC registration")
    o3d.utility.random.seed(seed)
    with open3d_threads(1 if repeatable else None):
        return _ransac(
            o3d,
            template,
            source,
            voxel_size,
            max_iterations,
            confidence,
            downsample,
            orient_normals,
        )


def _ransac(
    o3d,
    template: np.ndarray,
    source: np.ndarray,
    voxel_size: float,
    max_iterations: int,
    confidence: float,
    downsample: bool = False,
    orient: bool = False,
) -> tuple[np.ndarray, float, float]:
    src, src_f = _cloud_and_features(o3d, source, voxel_size, downsample, orient)
    tpl, tpl_f = _cloud_and_features(o3d, template, voxel_size, downsample, orient)
    result = ransac_on_features(o3d, tpl, src, tpl_f, src_f, voxel_size, max_iterations, confidence)
    return np.asarray(result.transformation), result.fitness, result.inlier_rmse


def ransac_on_features(
    o3d: Any,
    template: Any,
    source: Any,
    template_features: Any,
    source_features: Any,
    voxel_size: float,
    max_iterations: int = 100_000,
    confidence: float = 0.999,
) -> Any:
    """Open3D's RANSAC on mutual FPFH matches of two Open3D clouds (template, then source,
    masknet's order) with the tutorial's settings: inlier distance 1.5 voxels, edge-length
    and distance checkers. Returns Open3D's ``RegistrationResult`` (source -> template)."""
    reg = o3d.pipelines.registration
    distance, settings = _tutorial_settings(reg, voxel_size, max_iterations, confidence)
    return reg.registration_ransac_based_on_feature_matching(
        source, template, source_features, template_features, True, distance, *settings
    )


def ransac_on_matches(
    o3d: Any,
    template: Any,
    source: Any,
    matches: np.ndarray,
    voxel_size: float,
    max_iterations: int = 100_000,
    confidence: float = 0.999,
) -> Any:
    """:func:`ransac_on_features` on given matches (K, 2) int: (source index, template
    index) pairs, as :func:`~masknet.registration.solvers.correspondences.feature_matches` gives
    them. The same settings; the same pose for the same matches and seed."""
    reg = o3d.pipelines.registration
    distance, settings = _tutorial_settings(reg, voxel_size, max_iterations, confidence)
    pairs = o3d.utility.Vector2iVector(np.ascontiguousarray(matches, dtype=np.int32))
    return reg.registration_ransac_based_on_correspondence(
        source, template, pairs, distance, *settings
    )


def _tutorial_settings(reg: Any, voxel_size: float, max_iterations: int, confidence: float):
    """The tutorial's inlier distance (1.5 voxels) and RANSAC's other arguments after it:
    point-to-point estimation, 3 matches a draw, edge-length and distance checkers, and
    the convergence criteria."""
    distance = RANSAC_INLIER_VOXELS * voxel_size
    checkers = [
        reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
        reg.CorrespondenceCheckerBasedOnDistance(distance),
    ]
    criteria = reg.RANSACConvergenceCriteria(max_iterations, confidence)
    return distance, (reg.TransformationEstimationPointToPoint(False), 3, checkers, criteria)


def open3d_fgr(
    template: np.ndarray,
    source: np.ndarray,
    voxel_size: float = 0.05,
    orient_normals: bool = False,
) -> tuple[np.ndarray, float, float]:
    """Fast Global Registration (Zhou et al., 2016) on FPFH features (Open3D); returns
    (transform (4, 4), fitness, inlier_rmse).

    Arguments in masknet's order: template (N, 3), then source (M, 3), the points to move.
    ``orient_normals`` as :func:`open3d_fpfh_ransac`'s.
    """
    o3d = require_open3d("Open3D fast global registration")
    reg = o3d.pipelines.registration
    src, src_f = _cloud_and_features(o3d, source, voxel_size, orient=orient_normals)
    tpl, tpl_f = _cloud_and_features(o3d, template, voxel_size, orient=orient_normals)
    option = reg.FastGlobalRegistrationOption(maximum_correspondence_distance=0.5 * voxel_size)
    o3d.utility.random.seed(0)  # FGR draws its tuples from Open3D's global generator
    result = reg.registration_fgr_based_on_feature_matching(src, tpl, src_f, tpl_f, option)
    return np.asarray(result.transformation), result.fitness, result.inlier_rmse
