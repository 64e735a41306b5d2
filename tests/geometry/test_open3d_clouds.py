"""masknet.geometry.open3d_clouds: the one builder of Open3D clouds, and reading them back."""

from __future__ import annotations

import numpy as np
import pytest

from masknet.geometry.open3d_clouds import from_open3d, to_open3d

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
