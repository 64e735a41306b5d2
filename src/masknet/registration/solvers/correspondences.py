"""Pose hypotheses from FPFH correspondences: features, mutual matches, a batched RANSAC.

The classical half of the coarse-to-fine pipeline (:mod:`masknet.registration.stages.search`).
Open3D computes the FPFH features on a voxel grid; everything after that is numpy on a
few hundred points:

1. :func:`feature_cloud`: voxel down-sampling, normals within 2 voxels and FPFH within
   5 voxels (Open3D's global-registration tutorial; at most 50 neighbours), for one cloud.
2. :func:`mutual_matches`: index pairs whose features are each other's nearest neighbour
   (33-D KD-trees).
3. :func:`ransac_poses`: minimal samples of 3 matches, all solved at once by a batched
   Kabsch, pruned by edge-length consistency, scored by the matches they explain; the
   best few distinct poses, each refitted on its inliers.
4. :func:`compatible_poses`: where few matches are right, RANSAC seldom draws three of
   them; the matches that agree with many others on their pairwise distances (spatial
   compatibility, as SC²-PCR seeds its search) give poses directly.

The voxel follows the clouds, not their unit: :func:`voxel_for` picks the size that
leaves about ``target`` template points, so the features see the same structure in
millimetres and in metres.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from scipy.spatial.distance import cdist

from masknet.geometry.align import rigid_transforms_numpy
from masknet.geometry.clouds import MIN_POINTS
from masknet.geometry.features import fpfh_features
from masknet.geometry.open3d_clouds import to_open3d
from masknet.geometry.se3 import transform_points
from masknet.io import require_open3d
from masknet.registration.judge.arbiter import most_matched

# Neighbours per FPFH, within 5 voxels. Open3D's tutorial takes 100; 50 costs a third
# less on the finest grid and matched as well on ModelNet40 pairs (clean, turned to 180°).
FPFH_NEIGHBOURS = 50

__all__ = [
    "FeatureCloud",
    "compatible_poses",
    "feature_cloud",
    "fpfh_features",
    "mutual_matches",
    "ransac_poses",
    "voxel_for",
]


class FeatureCloud(NamedTuple):
    """points: (P, 3) voxel centres, float64. features: (P, 33) FPFH, float64.
    voxel: the grid's edge, in the cloud's units."""

    points: np.ndarray
    features: np.ndarray
    voxel: float


def voxel_for(points: np.ndarray, target: int, radius: float) -> float:
    """A voxel edge that leaves about ``target`` of ``points`` (P, 3): a first try at
    ``radius / 20``, corrected twice for the area the cloud covers (count ~ 1 / voxel^2)."""
    cloud = to_open3d(points, feature="FPFH features")
    voxel = radius / 20
    for _ in range(2):
        count = len(cloud.voxel_down_sample(voxel).points)
        if count == 0 or abs(count - target) < 0.1 * target:
            break
        voxel *= np.sqrt(count / target)
    return float(voxel)


def feature_cloud(points: np.ndarray, voxel: float) -> FeatureCloud:
    """FPFH of ``points`` (P, 3) down-sampled on a grid of edge ``voxel``, normals oriented
    towards the grid's centroid."""
    o3d = require_open3d("FPFH features")
    down = to_open3d(points, feature="FPFH features").voxel_down_sample(voxel)
    fpfh = fpfh_features(o3d, down, voxel, FPFH_NEIGHBOURS, orient=True)
    return FeatureCloud(np.asarray(down.points), np.asarray(fpfh.data).T.copy(), voxel)


# Above this many source-template feature pairs, the matches come from KD-trees: the
# distance matrix of a room's 9,500 x 6,800 FPFH features took 2.5 s on one BLAS thread,
# Open3D's feature KD-trees 0.3 s with the same matches; at 300 x 300 the matrix is
# faster (1.3 ms against 1.8 ms).
MATRIX_MATCHES = 1_000_000


def mutual_matches(source: np.ndarray, template: np.ndarray) -> np.ndarray:
    """(K, 2) index pairs (source row, template row) of features (S, D) and (T, D) that are
    each other's nearest neighbour; all of the source's nearest where fewer than 3 are."""
    if len(source) == 0 or len(template) == 0:
        return np.empty((0, 2), np.int64)
    if len(source) * len(template) > MATRIX_MATCHES:
        return _tree_matches(source, template)
    # A few hundred features each: one distance matrix beats two 33-D KD-trees.
    d2 = (source**2).sum(1)[:, None] - 2 * source @ template.T + (template**2).sum(1)[None]
    to_template = d2.argmin(1)
    to_source = d2.argmin(0)
    rows = np.arange(len(source))
    mutual = to_source[to_template] == rows
    if mutual.sum() < MIN_POINTS:
        mutual[:] = True
    return np.stack([rows[mutual], to_template[mutual]], axis=1)


def _tree_matches(source: np.ndarray, template: np.ndarray) -> np.ndarray:
    """:func:`mutual_matches` through Open3D's feature KD-trees, for feature sets too large
    for one matrix."""
    reg = require_open3d("FPFH features").pipelines.registration

    def feature(rows: np.ndarray):
        out = reg.Feature()
        out.data = np.ascontiguousarray(rows.T, dtype=np.float64)
        return out

    return feature_matches(feature(source), feature(template))


def feature_matches(source: Any, template: Any) -> np.ndarray:
    """:func:`mutual_matches` of two Open3D ``Feature`` objects (FPFH, as
    :func:`fpfh_features` gives them), through Open3D's ``correspondences_from_features``
    (the matches of its feature-matching RANSAC with the mutual filter). (K, 2) int64."""
    reg = require_open3d("FPFH features").pipelines.registration
    found = np.asarray(reg.correspondences_from_features(source, template, True))
    if len(found) < MIN_POINTS:
        found = np.asarray(reg.correspondences_from_features(source, template, False))
    return found.astype(np.int64).reshape(-1, 2)


class PoseHypotheses(NamedTuple):
    """transform: (H, 4, 4) source -> template, best first. inliers: (H,) matches each
    explains within the threshold."""

    transform: np.ndarray
    inliers: np.ndarray


def ransac_poses(
    source: np.ndarray,
    template: np.ndarray,
    threshold: float,
    trials: int = 1000,
    keep: int = 3,
    seed: int = 0,
    distinct_deg: float = 10.0,
    confidence: float = 0.999,
    chunk: int = 250,
) -> PoseHypotheses:
    """The ``keep`` best distinct poses that put matched points source (K, 3) onto
    template (K, 3) within ``threshold``.

    Samples of 3 matches are drawn and solved ``chunk`` at a time, in one batch each;
    samples whose edge lengths disagree by over 10% (a rigid motion keeps them) are dropped
    first. Drawing stops after ``trials`` samples, or earlier once the best inlier share w
    so far makes another all-inlier sample unlikely to be missed: the usual
    log(1 - confidence) / log(1 - w^3) samples. Poses closer than ``distinct_deg`` degrees
    and three thresholds of translation to a better one are duplicates. Each kept pose is
    refitted on its inliers.
    """
    k = len(source)
    empty = PoseHypotheses(np.empty((0, 4, 4)), np.empty(0, np.int64))
    if k < MIN_POINTS:
        return empty
    rng = np.random.default_rng(seed)
    all_poses, all_near = [], []
    drawn, best = 0, 0
    while drawn < trials:
        size = min(chunk, trials - drawn)
        drawn += size
        if k < 8:
            picks = np.stack([rng.choice(k, 3, replace=False) for _ in range(size)])
        else:
            picks = rng.integers(0, k, (size, 3))
        picks = picks[
            (picks[:, 0] != picks[:, 1])
            & (picks[:, 1] != picks[:, 2])
            & (picks[:, 0] != picks[:, 2])
        ]
        s, t = source[picks], template[picks]  # (T, 3, 3)
        edges_s = np.linalg.norm(s - np.roll(s, 1, axis=1), axis=-1)
        edges_t = np.linalg.norm(t - np.roll(t, 1, axis=1), axis=-1)
        consistent = (np.minimum(edges_s, edges_t) >= 0.9 * np.maximum(edges_s, edges_t)).all(1)
        consistent &= edges_s.min(1) > threshold  # a degenerate sample fixes no rotation
        if consistent.any():
            poses = rigid_transforms_numpy(s[consistent], t[consistent])
            near = matches_within(poses, source, template, threshold)  # (H, K)
            all_poses.append(poses)
            all_near.append(near)
            best = max(best, int(near.sum(1).max()))
        share = best / k
        if 0 < share < 1 and drawn >= np.log(1 - confidence) / np.log(1 - share**3):
            break
        if share == 1:
            break
    if not all_poses:
        return empty
    poses, near = np.concatenate(all_poses), np.concatenate(all_near)
    counts = near.sum(1)
    # Greedy: the best pose, then the best of those not within distinct_deg and three
    # thresholds of translation of one already chosen.
    chosen = most_matched(poses, counts, keep, distinct_deg, 3 * threshold)
    return PoseHypotheses(_refit(source, template, near[chosen]), counts[chosen])


def compatible_poses(
    source: np.ndarray,
    template: np.ndarray,
    threshold: float,
    seeds: int = 10,
    group: int = 30,
    max_matches: int = 1000,
    seed: int = 0,
) -> PoseHypotheses:
    """Poses from groups of mutually compatible matches source (K, 3) -> template (K, 3).

    Two matches are compatible when their source points and their template points lie
    equally far apart (within ``threshold``, and farther than it: a rigid motion keeps
    distances). Right matches are all compatible with each other; wrong ones agree only
    by chance. The ``seeds`` matches compatible with the most others each take the
    ``group`` matches sharing the most compatible partners with them (second-order
    compatibility, Chen et al., SC²-PCR, CVPR 2022), and the pose of that group, refitted
    on every match it explains within ``threshold``, is a hypothesis. Unlike RANSAC's
    draws of three, this finds the right pose when a few percent of the matches are right
    (a re-sampled view of a cluttered scene: 6 of 510). Above ``max_matches`` matches, a
    seeded random subset of that many forms the groups."""
    k = len(source)
    empty = PoseHypotheses(np.empty((0, 4, 4)), np.empty(0, np.int64))
    if k < MIN_POINTS or seeds < 1:
        return empty
    rows = np.arange(k)
    if k > max_matches:
        rows = np.sort(np.random.default_rng(seed).choice(k, max_matches, replace=False))
    s, t = source[rows], template[rows]
    d_s, d_t = cdist(s, s), cdist(t, t)
    compatible = (np.abs(d_s - d_t) < threshold) & (np.minimum(d_s, d_t) > threshold)
    c = compatible.astype(np.float32)
    leaders = np.argsort(-c.sum(1), kind="stable")[:seeds]
    second = c[leaders] * (c[leaders] @ c)  # (seeds, K'): partners shared, where compatible
    members = np.argsort(-second, axis=1, kind="stable")[:, :group]
    weights = np.zeros((len(leaders), k))
    for i, (leader, team) in enumerate(zip(leaders, members, strict=True)):
        team = team[second[i, team] > 0]
        if len(team) >= 2:  # with its leader, three matches at least: a rotation
            weights[i, rows[np.append(team, leader)]] = 1.0
    weights = weights[weights.sum(1) >= MIN_POINTS]
    if not len(weights):
        return empty
    poses = _refit(source, template, weights)
    near = matches_within(poses, source, template, threshold)
    near = near[near.sum(1) >= MIN_POINTS]
    return PoseHypotheses(_refit(source, template, near), near.sum(1))


def matches_within(
    poses: np.ndarray, source: np.ndarray, template: np.ndarray, threshold: float
) -> np.ndarray:
    """(H, K) bool: the matches, source (K, 3) to template (K, 3), that each of ``poses``
    (H, 4, 4) brings within ``threshold``: a pose's consensus."""
    return ((transform_points(poses, source[None]) - template) ** 2).sum(-1) <= threshold**2


def _refit(source: np.ndarray, template: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(H, 4, 4): for each row of ``weights`` (H, K), bool or float, the pose that best puts
    the weighted matches source (K, 3) onto template (K, 3)."""
    batch = (len(weights), len(source), 3)
    return rigid_transforms_numpy(
        np.broadcast_to(source, batch),
        np.broadcast_to(template, batch),
        np.asarray(weights, dtype=np.float64),
    )
