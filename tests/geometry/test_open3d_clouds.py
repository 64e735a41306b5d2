"""masknet.geometry.open3d_clouds: the one builder of Open3D clouds, and reading them back."""

from __future__ import annotations

import numpy as np
import pytest

from masknet.geometry.open3d_clouds import (
    from_open3d,
    grid_normals,
    to_open3d,
    undefined_normals,
)

o3d = pytest.importorskip("open3d")


def test_a_cloud_round_trips_with_its_normals_and_colours():
    rng = np.random.default_rng(0)
    points, normals, colours = (
        rng.normal(size=(50, 3)),
        rng.normal(size=(50, 3)),
        rng.random((50, 3)),
    )
    cloud = to_open3d(points, normals=normals, colors=colours)
    np.testing.assert_array_equal(np.asarray(cloud.points), points)
    np.testing.assert_array_equal(np.asarray(cloud.normals), normals)
    np.testing.assert_array_equal(np.asarray(cloud.colors), colours)
    assert not to_open3d(points, normals=normals[:10]).has_normals()  # a wrong length is left out
    np.testing.assert_array_equal(from_open3d(cloud), points)


def test_tensor_clouds_are_read_and_anything_else_is_not_a_cloud():
    points = np.arange(12, dtype=np.float32).reshape(4, 3)
    tensor = o3d.t.geometry.PointCloud(o3d.core.Tensor(points))
    np.testing.assert_array_equal(from_open3d(tensor), points)
    assert from_open3d(points) is None and from_open3d("cloud.ply") is None


def _rings_on_a_wall() -> np.ndarray:
    """A wall (the plane y = 0) seen as a lidar sees it: horizontal lines 0.1 apart, points
    0.01 apart along each, 21 lines of 101 points."""
    x, z = np.meshgrid(np.linspace(0.0, 1.0, 101), np.linspace(0.0, 2.0, 21))
    return np.stack([x.ravel(), np.zeros(x.size), z.ravel()], axis=1)


def test_normals_on_lidar_rings_come_from_the_nearest_points_not_the_ring():
    wall = _rings_on_a_wall()
    # Within 0.03 each point has only its own line: Open3D's normal is undefined there.
    alone = to_open3d(wall)
    alone.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.03, max_nn=30))
    assert np.mean(np.abs(np.asarray(alone.normals)[:, 1]) < 0.9) > 0.5
    cloud = to_open3d(wall)
    grid_normals(cloud, 0.03)
    np.testing.assert_allclose(np.abs(np.asarray(cloud.normals)[:, 1]), 1.0, atol=1e-6)


def test_normals_of_a_surface_with_a_few_rings_are_open3d_s_own():
    rng = np.random.default_rng(0)
    surface = np.c_[rng.random((3000, 2)), 0.002 * rng.random(3000)]
    rings = _rings_on_a_wall()[:303] + [2.0, 0.0, 0.0]  # 3 lines, apart from the surface
    points = np.vstack([surface, rings])
    undefined = undefined_normals(points, 0.04)
    assert undefined[3000:].all() and 0 < undefined.mean() < 0.5  # the lines, a minority
    cloud, theirs = to_open3d(points), to_open3d(points)
    grid_normals(cloud, 0.04)
    theirs.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.04, max_nn=30))
    np.testing.assert_array_equal(np.asarray(cloud.normals), np.asarray(theirs.normals))
