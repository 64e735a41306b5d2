"""Adapters of the ICP back-ends: :func:`masknet.registration.solvers.icp.icp` and Open3D's ICP."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from masknet.errors import MaskNetError
from masknet.registration.solvers.backends.base import BackendRun, points_in_use, usable
from masknet.registration.solvers.icp import icp
from masknet.registration.solvers.open3d_icp import open3d_icp
from masknet.registration.terms.options import ICPCriteria, Open3DICPOptions, as_dict

__all__ = ["run_icp", "run_open3d_icp"]


def run_icp(
    template: np.ndarray,
    source: np.ndarray,
    mask: np.ndarray | None,
    source_mask: np.ndarray | None,
    options: ICPCriteria,
) -> BackendRun:
    """ICP on the template points in use and the kept source points. A single pair runs the
    KD-tree branch in numpy float64; a batch the batched torch branch in float32, about
    twice as fast as float64 and exact enough in the call's frame (centred, unit scale).

    template (B, N, 3), source (B, M, 3), mask (B, N) and source_mask (B, M) bool or None."""
    try:
        if template.shape[0] == 1:  # one pair: the KD-tree branch, no tensor
            target, moving = next(points_in_use(template, source, mask, source_mask))
            solution = icp(target, moving, **as_dict(options))
        else:
            keep = usable(source_mask)
            solution = icp(
                torch.from_numpy(template).float(),
                torch.from_numpy(source).float(),
                template_valid=None if mask is None else torch.from_numpy(mask),
                source_valid=None if keep is None else torch.from_numpy(keep),
                **as_dict(options),
            )
    except ValueError as exc:
        raise MaskNetError(f"icp: {exc}") from exc
    return BackendRun(np.asarray(solution.transform, dtype=np.float64), icp_info(solution))


def icp_info(solution: Any) -> dict[str, np.ndarray]:
    """The ``info`` of an :class:`~masknet.registration.solvers.icp.ICPSolution`, as numpy (B,)."""
    return {
        "converged": np.asarray(solution.converged),
        "fitness": np.asarray(solution.fitness, dtype=np.float64),
        "inlier_rmse": np.asarray(solution.inlier_rmse, dtype=np.float64),
        "iterations": np.asarray(solution.iterations),
    }


def run_open3d_icp(
    template: np.ndarray,
    source: np.ndarray,
    mask: np.ndarray | None,
    source_mask: np.ndarray | None,
    options: Open3DICPOptions,
) -> BackendRun:
    """Open3D's point-to-point ICP, pair by pair, on the template points in use and the
    kept source points."""
    parts = []
    for target, moving in points_in_use(template, source, mask, source_mask):
        try:
            parts.append(open3d_icp(template=target, source=moving, **as_dict(options)))
        except (ValueError, TypeError) as exc:
            raise MaskNetError(f"open3d-icp: {exc}") from exc
    solution = type(parts[0])(*(torch.cat(field_parts) for field_parts in zip(*parts, strict=True)))
    return BackendRun(solution.transform.double().numpy(), icp_info(solution))
