"""Point clouds as the networks take them: validated (B, N, 3) batches, and their scale."""

from __future__ import annotations

import os
from typing import Any, NamedTuple

import numpy as np
import torch
from torch import Tensor

from masknet.errors import MaskNetError
from masknet.geometry.open3d_clouds import from_open3d

__all__ = [
    "MIN_POINTS",
    "SPACING_SAMPLE",
    "Frame",
    "as_cloud_batch",
    "check_pair",
    "centroid_radius",
    "median_spacing",
    "median_spread",
    "points_of",
    "principal_turn_deg",
    "rms_radius",
    "unit_radius",
]

# The fewest points a template or source may have for MaskNet and the registration networks.
MIN_POINTS = 3
# A frame holds float32 values only while every point lies within this many template
# radii of the template's centroid (float32 then resolves 6e-5 of a radius or finer).
SNAP_RADII = 1e3


def unit_radius(points: Any) -> Any:
    """A cloud's radius, the project's one: the largest distance from its bounding-box
    centre (how the training shapes were scaled). (B, N, 3) -> (B,), or (N, 3) -> (),
    numpy or torch alike; at least 1e-12."""
    if isinstance(points, Tensor):
        mid = (points.amax(-2, keepdim=True) + points.amin(-2, keepdim=True)) / 2
        return (points - mid).norm(dim=-1).amax(-1).clamp_min(1e-12)
    points = np.asarray(points, dtype=np.float64)
    mid = (points.max(-2, keepdims=True) + points.min(-2, keepdims=True)) / 2
    return np.maximum(np.linalg.norm(points - mid, axis=-1).max(-1), 1e-12)


def centroid_radius(points: Any) -> Any:
    """The largest distance of points from their centroid: (..., N, 3) -> (...), numpy
    (float64) or torch (its dtype). The robust search's scale (its first feature grid and
    its basins), the benchmark's voxel sweep of small_gicp, the success criteria, the
    scene search's reach and the training clutter's size are in it; :func:`unit_radius`
    (about the bounding-box centre) is the networks' scale."""
    if isinstance(points, Tensor):
        return (points - points.mean(-2, keepdim=True)).norm(dim=-1).amax(-1)
    points = np.asarray(points, dtype=np.float64)
    return np.linalg.norm(points - points.mean(-2, keepdims=True), axis=-1).max(-1)


# median_spread measures clouds larger than this on a seeded random subset of this size:
# a median over 65,536 points moves by well under a per cent, and a million-point scan's
# unit and scene checks cost 0.27 s on every point.
SPREAD_POINTS = 65_536


def median_spread(points: np.ndarray) -> float:
    """The median distance of points (P, 3) from their coordinate-wise median: a cloud's
    extent that stray points and outliers, even a third of them, barely move."""
    from masknet.geometry.sampling import random_subset

    points = random_subset(np.asarray(points, dtype=np.float64), SPREAD_POINTS)
    return float(np.median(np.linalg.norm(points - np.median(points, axis=0), axis=1)))


def rms_radius(points: np.ndarray) -> np.ndarray:
    """The root mean square distance of points from their centroid: (..., N, 3) -> (...),
    float64. The call's frame is scaled by it, and the verdict measures shifts in it."""
    points = np.asarray(points, dtype=np.float64)
    centre = points.mean(-2, keepdims=True)
    return np.sqrt(((points - centre) ** 2).sum(-1).mean(-1))


# A principal axis is defined where its variance is at least this many times that of each
# neighbour in rank, in both clouds: between two close variances a partial view swaps them.
AXIS_GAP = 2.0


def principal_turn_deg(
    template: np.ndarray, source: np.ndarray, min_gap: float = AXIS_GAP
) -> float:
    """A lower bound, in degrees, of the rotation between two clouds of one shape: the
    largest angle between a principal axis of ``template`` (N, 3) and the source's (M, 3)
    of the same rank, over the axes defined in both (``min_gap``); 0 where none is. Axes
    have no sign, so it is at most 90 degrees, and it is blind to turns about an axis.

    A partial source moves its axes: on ModelNet40 pairs keeping 70% of the points and
    turned at most 45 degrees, 1 pair in 100 read 50 degrees or more; turned up to 180
    degrees, half of them did."""

    def axes(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        centred = np.asarray(points, dtype=np.float64)
        centred = centred - centred.mean(0)
        variances, vectors = np.linalg.eigh(centred.T @ centred / max(len(centred), 1))
        # Descending; variances at rounding level (a line's, a plane's) tie at a floor
        # relative to the largest, so that their axes stay undefined.
        variances = variances[::-1]
        variances = np.maximum(variances, variances[0] * 1e-12 + 1e-300)
        gaps = variances[:-1] / variances[1:]  # rank i against rank i + 1
        defined = np.minimum(np.append(gaps, np.inf), np.insert(gaps, 0, np.inf))
        return defined >= min_gap, vectors[:, ::-1]

    defined_t, axes_t = axes(template)
    defined_s, axes_s = axes(source)
    both = defined_t & defined_s
    if not both.any():
        return 0.0
    cosines = np.abs(np.sum(axes_t[:, both] * axes_s[:, both], axis=0))
    return float(np.degrees(np.arccos(np.clip(cosines.min(), 0.0, 1.0))))


def points_of(cloud: Any) -> Any:
    """An Open3D point cloud's (P, 3) points; anything else as it is."""
    points = from_open3d(cloud)
    return cloud if points is None else points


def check_pair(
    template: Any, source: Any, names: tuple[str, str] = ("template", "source")
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Validate clouds, template (N, 3) or (B, N, 3) and source (M, 3) or (B, M, 3) (arrays,
    or Open3D point clouds, legacy or tensor);
    return them as batches (B, N, 3), (B, M, 3) (numpy, as given) and whether the input
    was one pair. Messages name the clouds by ``names``.

    Raises:
        MaskNetError: mismatched or wrong shapes, different batch sizes, or a cloud that
            :func:`masknet.io_checks.check_cloud` refuses (not numbers, transposed, fewer
            than :data:`MIN_POINTS` points, NaN or inf, overflow, no 3-D extent).

    Warns:
        MaskNetWarning: a cloud of 3-10 points, or one point far out.
    """
    from masknet.errors import clouds_checked
    from masknet.io_checks import ARRAY_NONFINITE_HINT, check_cloud

    for name, cloud in zip(names, (template, source), strict=True):
        if isinstance(cloud, str | os.PathLike):  # a file name where points belong
            raise MaskNetError(
                f"{name} is a path ({os.fspath(cloud)!r}), not points: read it first, "
                "points = masknet.io.read_points(path)"
            )
    # Open3D point clouds (legacy and tensor) are taken as their points.
    template, source = (points_of(cloud) for cloud in (template, source))
    t, s = np.asarray(template), np.asarray(source)
    if t.ndim != s.ndim or t.ndim not in (2, 3):
        raise MaskNetError(
            f"template and source must both be (N,3) or (B,N,3); got {t.shape} and {s.shape}"
        )
    single = t.ndim == 2
    if single:
        t, s = t[None], s[None]
    if t.shape[0] != s.shape[0]:
        raise MaskNetError(f"batch sizes differ: template {t.shape[0]}, source {s.shape[0]}")
    for name, a in zip(names, (t, s), strict=True):
        if a.shape[-1] != 3 and not (a.shape[1] == 3 and a.shape[-1] > 3):
            shape = a.shape[1:] if single else a.shape  # the shape the caller gave
            raise MaskNetError(f"{name} must have 3 columns (x, y, z); got shape {shape}")
        if clouds_checked():  # an entry point checked them already (errors.checks_done)
            continue
        for i, cloud in enumerate(a):  # the checks of every file read, cloud by cloud
            label = name if single else f"{name} {i}"
            check_cloud(cloud, label, nonfinite_hint=ARRAY_NONFINITE_HINT)
    return t, s, single


def as_cloud_batch(
    template: Any, source: Any, names: tuple[str, str] = ("template", "source")
) -> tuple[Tensor, Tensor, bool]:
    """:func:`check_pair`, then the clouds as float32 tensors (B, N, 3), (B, M, 3), moved
    into torch together in one conversion."""
    t, s, single = check_pair(template, source, names)
    both = torch.from_numpy(np.concatenate([t, s], axis=1).astype(np.float32))
    return both[:, : t.shape[1]], both[:, t.shape[1] :], single


# Points a cloud's spacing is measured on (a seeded subset of larger clouds): the median
# over 4,096 points' nearest neighbours is as good as that over millions, at a fraction.
SPACING_SAMPLE = 4096


def median_spacing(
    points: np.ndarray, tree: object | None = None, sample: int | None = None
) -> float:
    """The cloud's point spacing: the median of the distances from each point of
    ``points`` (P, 3) to its three nearest other points, in the cloud's units. On an
    evenly sampled surface that is about 1.45 times the median nearest-neighbour distance
    (1.38-1.53 on ModelNet40 shapes); every "spacing" in masknet (the fit's 1.5 spacings,
    ICP's pair cut-off, the refinement rule) is this one. Exact duplicates (merged scans
    often hold every point twice) say nothing of the spacing, so zero distances are
    skipped. ``tree``: a tree of ``points`` (:func:`masknet.geometry.knn.cloud_tree`)
    built by the caller; ``sample``: ask at most this many points (a seeded random
    subset; None asks every point). A cloud of one repeated point has spacing 0."""
    from masknet.geometry.knn import cloud_tree

    cloud = np.ascontiguousarray(points, dtype=np.float64)
    tree = cloud_tree(cloud) if tree is None else tree
    queries = cloud
    if sample is not None and len(cloud) > sample:
        queries = cloud[np.random.default_rng(0).choice(len(cloud), sample, replace=False)]
    k = min(len(cloud), 4)
    d, _ = tree.query(queries, k=k)
    d = np.asarray(d).reshape(len(queries), k)[:, 1:]
    positive = d[d > 0]
    return float(np.median(positive)) if len(positive) else 0.0


class Frame(NamedTuple):
    """One unit-free frame for a call: points ``x`` become ``(x - centre) / scale``.

    centre: (B, 3), each template's centroid. scale: one number for the batch, the mean
    RMS radius of the templates about their centroids. snap: coordinates in the frame
    are held as float32 values (6e-8 of a radius near the template): a cloud given in
    metres and the same cloud in millimetres then land on the same numbers in nearly
    every coordinate, where float64 would keep last-bit differences that voxel grids,
    ties between neighbours and random consensus can amplify into different answers.
    Where a cloud lies farther than :data:`SNAP_RADII` radii from the template, float32
    would cost precision, and the frame keeps float64.
    """

    centre: np.ndarray
    scale: float
    snap: bool = True

    @classmethod
    def of(cls, template: np.ndarray, *others: np.ndarray) -> Frame:
        """The frame of templates (B, N, 3), for them and ``others`` (B, P, 3)."""
        centre = template.mean(1)
        radii = rms_radius(template)
        scale = float(radii.mean()) if radii.mean() > 0 else 1.0
        reach = max(float(np.abs(c - centre[:, None]).max()) for c in (template, *others))
        return cls(centre, scale, reach <= SNAP_RADII * scale)

    def points_in(self, points: np.ndarray) -> np.ndarray:
        """(B, P, 3) input points -> the frame (float64, holding float32 values when
        ``snap``)."""
        inside = (points - self.centre[:, None]) / self.scale
        return inside.astype(np.float32).astype(np.float64) if self.snap else inside

    def transforms_out(self, transforms: np.ndarray) -> np.ndarray:
        """(B, 4, 4) source -> template transforms in the frame -> in input units."""
        out = np.array(transforms, dtype=np.float64)
        rot = out[:, :3, :3]
        out[:, :3, 3] = (
            self.scale * out[:, :3, 3] + self.centre - np.einsum("bij,bj->bi", rot, self.centre)
        )
        return out
