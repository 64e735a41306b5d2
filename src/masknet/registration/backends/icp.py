"""Adapters of the ICP back-ends: the batched torch ICP and Open3D's ICP."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from masknet.errors import MaskNetError
from masknet.registration.backends.base import BackendRun
from masknet.registration.icp import icp
from masknet.registration.icp_tree import icp_single
from masknet.registration.open3d_icp import open3d_icp

__all__ = ["run_icp", "run_open3d_icp"]


def run_icp(
    template: np.ndarray, source: np.ndarray, mask: np.ndarray | None, options: dict
) -> BackendRun:
    """ICP about the template's centroid. A single pair runs the KD-tree loop of
    :mod:`masknet.registration.icp_tree` in float64; a batch runs the batched torch ICP
    in float32, about twice as fast as float64 and exact enough wherever the clouds sit
    (far from the origin float32 alone would not be).

    template (B, N, 3), source (B, M, 3), mask (B, N) bool or None."""
    valid = None if mask is None else torch.from_numpy(mask)
    if mask is None:
        shift = template.mean(axis=1, keepdims=True)  # (B, 1, 3)
    else:  # the points in use only, so that masked-out points cannot change anything
        weights = mask[..., None].astype(np.float64)
        shift = (template * weights).sum(1, keepdims=True) / np.maximum(
            weights.sum(1, keepdims=True), 1
        )
    try:
        if template.shape[0] == 1:  # one pair: the KD-tree loop in float64 is faster
            points = template[0] if mask is None else template[0][mask[0]]
            _check_icp_options(options)
            solution = icp_single(points - shift[0], source[0] - shift[0], **options)
        else:
            solution = icp(
                template=torch.from_numpy(template - shift).float(),
                source=torch.from_numpy(source - shift).float(),
                template_valid=valid,
                **options,
            )
    except ValueError as exc:
        raise MaskNetError(f"icp: {exc}") from exc
    centred = solution.transform.double().numpy()
    # T = Shift(c) @ T_centred @ Shift(-c): R unchanged, t = t_centred + c - R c.
    c = shift[:, 0]
    centred[:, :3, 3] += c - np.einsum("bij,bj->bi", centred[:, :3, :3], c)
    return BackendRun(centred, icp_info(solution))


def _check_icp_options(options: dict) -> None:
    """The checks :func:`icp` makes of its options, for the single-pair loop."""
    if options.get("max_iterations", 10) < 0:
        raise ValueError(f"max_iterations must be >= 0, got {options['max_iterations']}")
    distance = options.get("max_correspondence_distance")
    if distance is not None and not distance > 0:
        raise ValueError(f"max_correspondence_distance must be positive, got {distance}")


def icp_info(solution: Any) -> dict[str, np.ndarray]:
    """The ``info`` of an :class:`~masknet.registration.icp.ICPSolution`, as numpy (B,)."""
    return {
        "converged": solution.converged.numpy(),
        "fitness": solution.fitness.double().numpy(),
        "inlier_rmse": solution.inlier_rmse.double().numpy(),
        "iterations": solution.iterations.numpy(),
    }


def run_open3d_icp(
    template: np.ndarray, source: np.ndarray, mask: np.ndarray | None, options: dict
) -> BackendRun:
    """Open3D's point-to-point ICP, pair by pair, on the template points in use."""
    parts = []
    for i in range(template.shape[0]):
        target = template[i] if mask is None else template[i][mask[i]]
        try:
            parts.append(open3d_icp(template=target, source=source[i], **options))
        except (ValueError, TypeError) as exc:
            raise MaskNetError(f"open3d-icp: {exc}") from exc
    solution = type(parts[0])(*(torch.cat(field_parts) for field_parts in zip(*parts, strict=True)))
    return BackendRun(solution.transform.double().numpy(), icp_info(solution))
