"""FPFH features of an Open3D cloud: the one implementation by Open3D, for the registration's
correspondences (:mod:`masknet.registration.solvers.correspondences`) and the mask networks'
descriptor inputs (:mod:`masknet.models.descriptors`; without Open3D, the same numbers come
from :mod:`masknet.geometry.fpfh`)."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["fpfh_features"]


def fpfh_features(o3d: Any, cloud: Any, voxel: float, neighbours: int, orient: bool) -> Any:
    """Open3D's FPFH ``Feature`` of an Open3D ``cloud`` at scale ``voxel``: normals from the
    points within 2 voxels (at most 30), features from those within 5 (at most
    ``neighbours``). Normals are estimated here where the cloud has none (with those
    settings: a cloud whose normals were estimated so keeps them).

    ``orient`` turns each normal towards the cloud's centroid. FPFH's angles change with
    the signs of the normals, and Open3D leaves each sign as its eigen-solver gives it,
    which depends on how the cloud lies in its frame: the same surface turned by a large
    angle then gets other features. Towards the centroid the sign follows the surface
    (inwards on a closed object, towards the middle of a scene). On ModelNet40 pairs turned
    up to 180 degrees, ``robust`` then stopped at the correspondences on every pair, in
    13 ms instead of 22 (docs/RESULTS.md)."""
    search = o3d.geometry.KDTreeSearchParamHybrid
    if not cloud.has_normals():
        cloud.estimate_normals(search(radius=2 * voxel, max_nn=30))
    if orient and len(cloud.points):
        cloud.orient_normals_towards_camera_location(np.asarray(cloud.points).mean(0))
    return o3d.pipelines.registration.compute_fpfh_feature(
        cloud, search(radius=5 * voxel, max_nn=neighbours)
    )
