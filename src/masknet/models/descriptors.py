"""Rotation-invariant per-point descriptors for the mask networks' inputs.

A network that reads coordinates alone sees a turned source as another shape; a local
descriptor of the surface around each point does not change with the turn. Ranking the
template points by how far their FPFH descriptor lies from the nearest source descriptor
(no learning at all) already picks the seen points with top-k precision 0.84 on ModelNet40
pairs turned up to 45 degrees (docs/RESULTS.md, CrossMaskNet).

:func:`pair_descriptors` gives each point of both clouds of a batch of pairs:

* its FPFH descriptor (Rusu et al. 2009; Open3D's, 33 bins in three 11-bin histograms,
  each summing to 200, divided here by 200), at a scale from the cloud's own median point
  spacing (:func:`~masknet.geometry.clouds.median_spacing`), so units do not matter, with
  normals turned towards the cloud's centroid (their sign then follows the surface, not
  the frame, as the registration's FPFH). The networks were trained on Open3D's features;
  without Open3D, :mod:`masknet.geometry.fpfh` computes the same numbers in numpy (no
  faster: Open3D's are used where it imports);
* one more channel: the distance from its descriptor to the nearest descriptor of the
  other cloud (small: some point of the other cloud looks like this one).
"""

from __future__ import annotations

from contextlib import nullcontext

import numpy as np
import torch
from torch import Tensor

from masknet._open3d import open3d_threads, require_open3d
from masknet.errors import MaskNetError
from masknet.geometry.clouds import median_spacing
from masknet.geometry.features import fpfh_features
from masknet.geometry.fpfh import hybrid_neighbours, open3d_fpfh
from masknet.geometry.open3d_clouds import to_open3d

__all__ = ["DESCRIPTOR_CHANNELS", "fpfh_descriptors", "pair_descriptors"]

# Per-point input channels each kind of descriptor adds: FPFH's 33 and the match distance.
DESCRIPTOR_CHANNELS = {"fpfh": 34}
# The FPFH scale in median spacings (normals from points within 2 scales, features from
# points within 5) and the most neighbours a feature reads: 30 instead of Open3D's usual
# 100 costs 10 ms a 1,024-point cloud instead of 38 (one thread), and the descriptors'
# ranking alone picks the seen points with top-k precision 0.824 instead of 0.839 (60 test
# pairs).
FPFH_SPACINGS = 2.0
FPFH_NEIGHBOURS = 30
# Open3D's normals read at most 30 neighbours (the registration's setting).
NORMAL_NEIGHBOURS = 30
# What needs Open3D, for the error raised when a cloud cannot be built.
FEATURE = "CrossMaskNet's FPFH descriptors (descriptors='fpfh')"


def fpfh_descriptors(points: np.ndarray, o3d: object | None = None) -> np.ndarray:
    """FPFH descriptors (P, 33) float32 in [0, 1] of a cloud ``points`` (P, 3), in any units
    (the scale is :data:`FPFH_SPACINGS` of the cloud's median spacing): Open3D's
    (:func:`masknet.geometry.features.fpfh_features` with ``orient=True``) divided by 200,
    by Open3D where ``o3d`` (its module) is given, else the same numbers by
    :func:`numpy_fpfh_descriptors`. A cloud of one repeated point gets zeros."""
    if o3d is None:
        return numpy_fpfh_descriptors(points)
    cloud = np.ascontiguousarray(points, dtype=np.float64)
    spacing = median_spacing(cloud) if len(cloud) > 1 else 0.0
    if spacing <= 0:
        return np.zeros((len(cloud), 33), np.float32)
    # Normals from points within 2 scales (at most 30), turned towards the centroid;
    # features from points within 5: the registration's settings.
    pc = to_open3d(cloud, feature=FEATURE)
    feature = fpfh_features(o3d, pc, FPFH_SPACINGS * spacing, FPFH_NEIGHBOURS, orient=True)
    return (np.asarray(feature.data).T / 200.0).astype(np.float32)


def numpy_fpfh_descriptors(points: np.ndarray) -> np.ndarray:
    """:func:`fpfh_descriptors` (P, 33) float32 without Open3D: normals from points within
    2 scales (at most 30), turned towards the centroid; features from points within 5 (at
    most :data:`FPFH_NEIGHBOURS`), by :mod:`masknet.geometry.fpfh`."""
    cloud = np.ascontiguousarray(points, dtype=np.float64)
    if len(cloud) < 2:
        return np.zeros((len(cloud), 33), np.float32)
    # One query serves the spacing, the normals and the features.
    idx, d2 = hybrid_neighbours(cloud, max(NORMAL_NEIGHBOURS, FPFH_NEIGHBOURS))
    # median_spacing's definition (the 3 nearest other points, zero distances skipped),
    # from the same tree's distances.
    near = np.sqrt(d2[:, 1:4])
    positive = near[near > 0]
    if not len(positive):
        return np.zeros((len(cloud), 33), np.float32)
    voxel = FPFH_SPACINGS * float(np.median(positive))
    feature = open3d_fpfh(
        cloud, 2 * voxel, 5 * voxel, NORMAL_NEIGHBOURS, FPFH_NEIGHBOURS, neighbours=(idx, d2)
    )
    return (feature / 200.0).astype(np.float32)


def _with_match(first: np.ndarray, second: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(P, 34) and (Q, 34): ``first`` (P, 33) and ``second`` (Q, 33), each row with its
    distance to the nearest row of the other."""
    # A few hundred to a thousand rows each: one distance matrix, no 33-D tree, read
    # along both axes.
    distance = torch.cdist(torch.from_numpy(first), torch.from_numpy(second))
    to_second, to_first = distance.amin(1).numpy(), distance.amin(0).numpy()
    return (
        np.concatenate([first, to_second[:, None]], axis=1),
        np.concatenate([second, to_first[:, None]], axis=1),
    )


def pair_descriptors(template: Tensor, source: Tensor, kind: str = "fpfh") -> tuple[Tensor, Tensor]:
    """Descriptors of each point of pairs (B, N, 3) and (B, M, 3): (B, N, C) and (B, M, C)
    float32 on the clouds' device, C = :data:`DESCRIPTOR_CHANNELS` ``[kind]`` (see the
    module's docs). Computed on the CPU (Open3D on torch's thread count where it imports,
    else numpy: the same numbers), without autograd.

    Raises:
        MaskNetError: an unknown ``kind``.
    """
    if kind not in DESCRIPTOR_CHANNELS:
        raise MaskNetError(
            f"descriptors must be one of {sorted(DESCRIPTOR_CHANNELS)}, got {kind!r}"
        )
    t_all = template.detach().float().cpu().numpy()
    s_all = source.detach().float().cpu().numpy()
    t_out, s_out = [], []
    try:
        o3d = require_open3d(FEATURE)
    except MaskNetError:
        o3d = None
    threads = nullcontext() if o3d is None else open3d_threads(torch.get_num_threads())
    with threads:
        for t, s in zip(t_all, s_all, strict=True):
            ft, fs = _with_match(fpfh_descriptors(t, o3d), fpfh_descriptors(s, o3d))
            t_out.append(ft)
            s_out.append(fs)
    as_tensor = lambda rows: torch.from_numpy(np.stack(rows)).to(template.device)  # noqa: E731
    return as_tensor(t_out), as_tensor(s_out)
