"""Open3D point clouds: the one place that builds them from arrays and reads them back.

Open3D is optional (``pip install masknet[open3d]``); nothing here imports it until a
cloud is built, and :func:`from_open3d` recognises an Open3D cloud without importing it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["to_open3d", "from_open3d"]


def to_open3d(
    points: Any,
    normals: Any | None = None,
    colors: Any | None = None,
    feature: str = "Open3D point clouds",
) -> Any:
    """An ``open3d.geometry.PointCloud`` of (P, 3) points, with (P, 3) normals and colours
    in [0, 1] where given (ignored when their length differs from the points').

    ``feature`` names what needs Open3D, for the error raised when it does not import.
    """
    from masknet.io import require_open3d

    o3d = require_open3d(feature)
    vectors = o3d.utility.Vector3dVector
    points = _writable(points)
    cloud = o3d.geometry.PointCloud(vectors(points))
    for name, values in (("normals", normals), ("colors", colors)):
        if values is not None and len(values) == len(points):
            values = _writable(values)
            setattr(cloud, name, vectors(values))
    return cloud


def _writable(values: Any) -> np.ndarray:
    """(P, 3) contiguous float64 that Open3D's vectors take: it copies them, but refuses a
    read-only buffer (a prepared template's), which is copied here first."""
    array = np.ascontiguousarray(np.asarray(values, dtype=np.float64).reshape(-1, 3))
    return array if array.flags.writeable else array.copy()


def from_open3d(cloud: Any) -> np.ndarray | None:
    """The (P, 3) float64 points of an Open3D point cloud (``open3d.geometry.PointCloud``
    or ``open3d.t.geometry.PointCloud``), or None for anything else.

    Checked by type name and module, so an array never imports Open3D.
    """
    kind = type(cloud)
    if kind.__name__ != "PointCloud" or not kind.__module__.startswith("open3d"):
        return None
    if hasattr(cloud, "point"):  # the tensor API: cloud.point.positions, an o3c.Tensor
        positions = cloud.point.positions.cpu()  # a cloud on a GPU comes to the host
        return np.asarray(positions.numpy(), dtype=np.float64).reshape(-1, 3)
    return np.asarray(cloud.points, dtype=np.float64).reshape(-1, 3)
