"""Adapter of Open3D's global registration on FPFH features (RANSAC, FGR)."""

from __future__ import annotations

import numpy as np
import torch

from masknet.geometry.clouds import unit_radius
from masknet.registration.backends.base import Backend, BackendRun

__all__ = ["open3d_global_backend"]


def open3d_global_backend(method: str) -> Backend:
    """The adapter of ``"open3d-ransac"`` or ``"open3d-fgr"``, pair by pair; ``voxel_size``
    is relative to each template's radius (default 0.05)."""

    def run(
        template: np.ndarray, source: np.ndarray, mask: np.ndarray | None, options: dict
    ) -> BackendRun:
        from masknet.registration.open3d_global import open3d_fgr, open3d_fpfh_ransac

        solver = open3d_fpfh_ransac if method == "open3d-ransac" else open3d_fgr
        options = dict(options)
        relative_voxel = options.pop("voxel_size", 0.05)
        transforms, fitness, rmse = [], [], []
        for i in range(template.shape[0]):
            target = template[i] if mask is None else template[i][mask[i]]
            radius = float(unit_radius(torch.from_numpy(template[i][None]))[0])
            tf, fit, err = solver(
                template=target, source=source[i], voxel_size=relative_voxel * radius, **options
            )
            transforms.append(tf)
            fitness.append(fit)
            rmse.append(err)
        info = {
            "fitness": np.asarray(fitness),
            "inlier_rmse": np.asarray(rmse),
            "iterations": np.full(len(fitness), -1),
        }
        return BackendRun(np.stack(transforms), info)

    return run
