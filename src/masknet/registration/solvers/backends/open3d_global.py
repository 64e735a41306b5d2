"""Adapters of Open3D's global registration on FPFH features (RANSAC, FGR)."""

from __future__ import annotations

import numpy as np

from masknet.geometry.clouds import unit_radius
from masknet.registration.solvers.backends.base import BackendRun, points_in_use
from masknet.registration.terms.options import FGROptions, RANSACOptions, as_dict

__all__ = ["run_fgr", "run_ransac"]


def run_ransac(
    template: np.ndarray,
    source: np.ndarray,
    mask: np.ndarray | None,
    source_mask: np.ndarray | None,
    options: RANSACOptions,
) -> BackendRun:
    """Open3D's RANSAC on FPFH features, pair by pair; ``voxel_size`` is relative to each
    template's radius (:func:`~masknet.geometry.clouds.unit_radius`, the networks' scale)."""
    from masknet.registration.solvers.open3d_global import open3d_fpfh_ransac

    return _run(open3d_fpfh_ransac, template, source, mask, source_mask, options)


def run_fgr(
    template: np.ndarray,
    source: np.ndarray,
    mask: np.ndarray | None,
    source_mask: np.ndarray | None,
    options: FGROptions,
) -> BackendRun:
    """Open3D's fast global registration on FPFH features, pair by pair; ``voxel_size``
    is relative to each template's radius (:func:`~masknet.geometry.clouds.unit_radius`)."""
    from masknet.registration.solvers.open3d_global import open3d_fgr

    return _run(open3d_fgr, template, source, mask, source_mask, options)


def _run(solver, template, source, mask, source_mask, options) -> BackendRun:
    settings = as_dict(options)
    relative_voxel = settings.pop("voxel_size")
    transforms, fitness, rmse = [], [], []
    pairs = points_in_use(template, source, mask, source_mask)
    for i, (target, moving) in enumerate(pairs):
        voxel = relative_voxel * float(unit_radius(template[i]))
        tf, fit, err = solver(template=target, source=moving, voxel_size=voxel, **settings)
        transforms.append(tf)
        fitness.append(fit)
        rmse.append(err)
    info = {
        "fitness": np.asarray(fitness),
        "inlier_rmse": np.asarray(rmse),
        "iterations": np.full(len(fitness), -1),
    }
    return BackendRun(np.stack(transforms), info)
