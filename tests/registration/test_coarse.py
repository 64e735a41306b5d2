"""masknet.registration.coarse: the pieces of the pipeline, and ICP from many starts."""

from __future__ import annotations

import numpy as np
from pykdtree.kdtree import KDTree
from scipy.spatial.transform import Rotation

from masknet.registration.coarse import (
    check_points,
    isolated_free,
    pose_fit,
    pose_fits,
    surface_points,
)
from masknet.registration.icp import icp, icp_from_starts


def test_isolated_points_are_found_and_a_sparse_cloud_keeps_all():
    rng = np.random.default_rng(0)
    surface = np.c_[rng.uniform(0, 1, (500, 2)), np.zeros(500)]
    stray = rng.uniform(5, 9, (20, 3))
    keep = isolated_free(np.concatenate([surface, stray]), 0.2)
    assert keep[:500].all() and not keep[500:].any()
    assert isolated_free(rng.uniform(0, 100, (50, 3)), 0.01).all()


def test_a_close_pair_of_outliers_is_no_surface_with_two_neighbours_asked():
    """Two stray points 0.1 apart keep each other at one neighbour, not at two (the
    check of auto's fast path and of robust's early exit); the surface keeps both."""
    rng = np.random.default_rng(0)
    surface = np.c_[rng.uniform(0, 1, (500, 2)), np.zeros(500)]
    pair = np.array([[5.0, 5, 5], [5.1, 5, 5]])
    cloud = np.concatenate([surface, pair])
    one, two = isolated_free(cloud, 0.2), isolated_free(cloud, 0.2, neighbours=2)
    assert one[500:].all() and not two[500:].any()
    assert one[:500].all() and two[:500].all()
    assert all((a == b).all() for a, b in zip(surface_points(cloud, 0.2), (one, two), strict=True))


def test_the_check_keeps_a_sparse_part_of_a_surface_that_is_more_than_a_few_points():
    """Stray pairs are dropped from the check; a sparse part (points in pairs 0.15 apart,
    0.5 between pairs: one neighbour each within 0.2) that is over 5% of the cloud is kept:
    it may be the part a wrong pose misfits."""
    rng = np.random.default_rng(0)
    dense = np.c_[rng.uniform(0, 1, (500, 2)), np.zeros(500)]
    pair = np.array([[5.0, 5, 5], [5.1, 5, 5]])
    few = np.concatenate([dense, pair])
    surface = isolated_free(few, 0.2)
    assert check_points(surface, isolated_free(few, 0.2, neighbours=2)).sum() == 500
    starts = 3 + 0.5 * np.arange(30)
    sparse = np.c_[np.sort(np.r_[starts, starts + 0.15]), np.zeros((60, 2))]
    many = np.concatenate([dense, sparse])
    surface = isolated_free(many, 0.2)
    assert surface[500:].all() and not isolated_free(many, 0.2, neighbours=2)[500:].any()
    assert (check_points(surface, isolated_free(many, 0.2, neighbours=2)) == surface).all()


def test_fit_counts_points_within_the_distance_and_batched_agrees():
    template = np.c_[np.arange(10.0), np.zeros((10, 2))]
    source = template[:4] + [0, 0.05, 0]
    far = np.eye(4)
    far[:3, 3] = [0, 1.0, 0]
    fit = pose_fit(KDTree(template), source, np.eye(4), 0.1)
    assert fit.fitness == 1.0 and abs(fit.rmse - 0.05) < 1e-12
    fits = pose_fits(KDTree(template), source, np.stack([np.eye(4), far]), 0.1)
    assert fits[0] == fit and fits[1].fitness == 0.0 and fits[1].score < fits[0].score


def test_icp_from_starts_equals_one_icp_per_start():
    rng = np.random.default_rng(1)
    template = rng.normal(size=(300, 3)) * [3, 2, 1]
    rot = Rotation.from_euler("xyz", [10, -20, 15], degrees=True).as_matrix()
    source = (template[:200] - [0.2, 0.1, 0]) @ rot
    starts = np.tile(np.eye(4), (3, 1, 1))
    starts[1, :3, :3] = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    starts[2, :3, :3] = Rotation.from_euler("x", 150, degrees=True).as_matrix()
    batched = icp_from_starts(KDTree(template), template, source, starts, 20)
    for h in range(3):
        one = icp(template, source, starts[h], 20, relative_rmse=0.0).transform[0]
        np.testing.assert_allclose(batched[h], one, atol=1e-8)
