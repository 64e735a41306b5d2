"""masknet.geometry.fpfh: Open3D's normals and FPFH, in numpy, against Open3D itself."""

from __future__ import annotations

import numpy as np
import pytest

from masknet.geometry.fpfh import hybrid_neighbours, open3d_fpfh, smallest_eigenvectors

# Largest |difference| allowed, in Open3D's units (each histogram sums to 200): the
# implementation follows Open3D's arithmetic step by step and agrees to ~1e-15.
TOLERANCE = {"fpfh vs open3d": 1e-9, "eigenvector": 1e-9}


def _open3d_fpfh(points: np.ndarray, normal_radius: float, feature_radius: float) -> np.ndarray:
    o3d = pytest.importorskip("open3d")
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    search = o3d.geometry.KDTreeSearchParamHybrid
    cloud.estimate_normals(search(radius=normal_radius, max_nn=30))
    cloud.orient_normals_towards_camera_location(points.mean(0))
    feature = o3d.pipelines.registration.compute_fpfh_feature(
        cloud, search(radius=feature_radius, max_nn=30)
    )
    return np.asarray(feature.data).T


def _ellipsoid(n: int, seed: int) -> np.ndarray:
    unit = np.random.default_rng(seed).normal(size=(n, 3))
    return unit / np.linalg.norm(unit, axis=1, keepdims=True) * [1.0, 0.6, 0.3]


def _rotation(seed: int) -> np.ndarray:
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q * np.sign(np.diag(r))


@pytest.mark.parametrize("seed", [0, 1])
def test_matches_open3d_on_a_surface_and_the_surface_turned(seed):
    points = _ellipsoid(400, seed)
    for cloud in (points, points @ _rotation(seed).T + [3.0, -1.0, 0.5]):
        ours = open3d_fpfh(cloud, 0.2, 0.5)
        theirs = _open3d_fpfh(cloud, 0.2, 0.5)
        assert np.abs(ours - theirs).max() < TOLERANCE["fpfh vs open3d"]
        sums = ours.reshape(-1, 3, 11).sum(-1)
        np.testing.assert_allclose(sums[sums.any(1)], 200.0, atol=1e-9)


def test_isolated_points_get_zeros_as_in_open3d():
    # Far points have no neighbour within either radius: identity covariance, no histogram;
    # a pair of points has fewer than 3 neighbours for its normal but features.
    far = [[9.0, 9.0, 9.0], [-9.0, 9.0, 9.0], [9.0, -9.0, 9.0], [9.05, -9.0, 9.0]]
    cloud = np.concatenate([_ellipsoid(300, 2), far])
    ours = open3d_fpfh(cloud, 0.2, 0.5)
    np.testing.assert_array_equal(ours[-4:-2], 0.0)
    assert ours[-2:].sum() > 0
    assert np.abs(ours - _open3d_fpfh(cloud, 0.2, 0.5)).max() < TOLERANCE["fpfh vs open3d"]


def test_a_flat_patch_puts_every_pair_in_the_middle_bins():
    # Coplanar points, parallel normals: every pair feature is 0, the middle of its range.
    # One far point above lifts the centroid off the plane, so that every normal turns up.
    grid = np.stack(np.meshgrid(np.arange(12.0), np.arange(12.0)), -1).reshape(-1, 2)
    jitter = np.random.default_rng(3).uniform(-0.2, 0.2, grid.shape)
    patch = np.column_stack([grid + jitter, np.zeros(len(grid))])
    cloud = np.concatenate([patch, [[5.0, 5.0, 50.0]]])
    ours = open3d_fpfh(cloud, 2.0, 3.0)
    middle = np.zeros(33)
    middle[[5, 16, 27]] = 200.0
    np.testing.assert_allclose(ours[:-1], np.broadcast_to(middle, patch.shape[:1] + (33,)))
    np.testing.assert_array_equal(ours[-1], 0.0)
    # On the plane alone the centroid lies in it: the signs are the rounding's, Open3D's too.
    for c in (cloud, patch):
        ours = open3d_fpfh(c, 2.0, 3.0)
        assert np.abs(ours - _open3d_fpfh(c, 2.0, 3.0)).max() < TOLERANCE["fpfh vs open3d"]


def test_exact_duplicates_match_open3d():
    points = _ellipsoid(300, 4)
    cloud = np.concatenate([points, points[:50]])
    ours = open3d_fpfh(cloud, 0.2, 0.5)
    assert np.abs(ours - _open3d_fpfh(cloud, 0.2, 0.5)).max() < TOLERANCE["fpfh vs open3d"]


def test_smallest_eigenvectors_are_those_of_eigh():
    rng = np.random.default_rng(5)
    a = rng.normal(size=(200, 3, 3))
    cov = a @ a.transpose(0, 2, 1)
    ours = smallest_eigenvectors(cov)
    reference = np.linalg.eigh(cov)[1][..., 0]
    assert np.abs(np.abs((ours * reference).sum(1)) - 1).max() < TOLERANCE["eigenvector"]
    # A zero matrix has none; a diagonal one, the axis of its smallest entry.
    special = np.stack([np.zeros((3, 3)), np.diag([3.0, 1.0, 2.0])])
    np.testing.assert_array_equal(smallest_eigenvectors(special), [[0, 0, 0], [0, 1, 0]])


def test_hybrid_neighbours_are_nearest_first_with_the_point_itself():
    points = _ellipsoid(100, 6)
    idx, d2 = hybrid_neighbours(points, 30)
    assert idx.shape == d2.shape == (100, 30)
    np.testing.assert_array_equal(idx[:, 0], np.arange(100))
    assert (np.diff(d2, axis=1) >= 0).all()
    few, _ = hybrid_neighbours(points[:5], 30)
    assert few.shape == (5, 5)
