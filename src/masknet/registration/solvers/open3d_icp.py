"""Open3D's point-to-point ICP for one pair, as an :class:`ICPSolution`.

A reference backend: ``open3d.pipelines.registration.registration_icp`` with
``TransformationEstimationPointToPoint``. Open3D's ``result.transformation`` maps
the source onto the target, which is masknet's convention (:mod:`masknet.geometry.se3`).
Open3D is optional; a missing install raises :class:`~masknet.errors.MaskNetError`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from masknet.geometry.open3d_clouds import to_open3d
from masknet.io import require_open3d
from masknet.registration.solvers.icp import ICPSolution

__all__ = ["open3d_icp", "point_to_plane_at_cuts"]


def open3d_icp(
    template: np.ndarray,
    source: np.ndarray,
    init: np.ndarray | None = None,
    max_iterations: int = 10,
    max_correspondence_distance: float | None = None,
    relative_fitness: float = 1e-6,
    relative_rmse: float = 1e-6,
    generalized: bool = False,
) -> ICPSolution:
    """Register one pair with Open3D's ICP: moves ``source`` onto ``template``.

    Arguments in masknet's order, ``(template, source)``, as :func:`masknet.register`.

    Args:
        template: (N, 3) target points.
        source: (M, 3) points to move.
        init: (4, 4) initial source -> template transform; None is the identity.
        max_iterations: Open3D's ``max_iteration``.
        max_correspondence_distance: Open3D's threshold; None uses 1e3, so that every
            pair counts (for unit-scale shapes).
        relative_fitness, relative_rmse: Open3D's convergence criteria (its defaults).
        generalized: Open3D's generalized ICP (plane-to-plane,
            ``registration_generalized_icp``) instead of point-to-point.

    Returns:
        ICPSolution with a batch of one: transform (1, 4, 4) float64, fitness and
        inlier_rmse (1,) float64. Open3D's legacy API reports neither the iteration
        count nor whether it converged, so ``iterations`` is -1 and ``converged`` is
        False. An empty template gives the identity with fitness 0.
    """
    o3d = require_open3d("the open3d ICP backend")
    reg = o3d.pipelines.registration
    src = np.ascontiguousarray(np.asarray(source, dtype=np.float64).reshape(-1, 3))
    tpl = np.ascontiguousarray(np.asarray(template, dtype=np.float64).reshape(-1, 3))
    init = np.eye(4) if init is None else np.asarray(init, dtype=np.float64)
    if init.shape != (4, 4):
        raise ValueError(f"init must be (4, 4), got {init.shape}")
    threshold = 1e3 if max_correspondence_distance is None else float(max_correspondence_distance)
    if len(tpl) == 0 or len(src) == 0:
        transform, fitness, rmse = init, 0.0, 0.0
    else:
        if generalized:
            run, estimation = (
                reg.registration_generalized_icp,
                reg.TransformationEstimationForGeneralizedICP(),
            )
        else:
            run, estimation = reg.registration_icp, reg.TransformationEstimationPointToPoint()
        result = run(
            to_open3d(src),
            to_open3d(tpl),
            threshold,
            init,
            estimation,
            reg.ICPConvergenceCriteria(
                relative_fitness=relative_fitness,
                relative_rmse=relative_rmse,
                max_iteration=int(max_iterations),
            ),
        )
        transform, fitness, rmse = (
            np.asarray(result.transformation),
            result.fitness,
            result.inlier_rmse,
        )
    return ICPSolution(
        torch.tensor(transform, dtype=torch.float64)[None],
        torch.zeros(1, dtype=torch.bool),
        torch.full((1,), -1, dtype=torch.int64),
        torch.tensor([fitness], dtype=torch.float64),
        torch.tensor([rmse], dtype=torch.float64),
    )


def point_to_plane_at_cuts(
    template: Any, source: Any, start: np.ndarray, cuts: tuple[float, ...], max_iteration: int
) -> tuple[np.ndarray, float]:
    """Open3D's point-to-plane ICP of the Open3D cloud ``source`` onto ``template`` (which
    has its normals) from ``start`` (4, 4), pairs cut at each of ``cuts`` (input units) in
    turn, ``max_iteration`` each: (transform (4, 4) source -> template, fitness at the last
    cut)."""
    o3d = require_open3d("point-to-plane ICP")
    reg = o3d.pipelines.registration
    pose, fitness = np.asarray(start, dtype=np.float64), 0.0
    for cut in cuts:
        result = reg.registration_icp(
            source,
            template,
            cut,
            pose,
            reg.TransformationEstimationPointToPlane(),
            reg.ICPConvergenceCriteria(max_iteration=max_iteration),
        )
        pose, fitness = np.asarray(result.transformation), float(result.fitness)
    return pose, fitness


def centroids_matched(template: Any, source: Any, iterations: int) -> np.ndarray:
    """The pose as given, brought into reach: the Open3D ``source`` cloud's centroid on the
    ``template``'s, then ``iterations`` of Open3D's point-to-point ICP with every pair (the
    paper's ICP step, without a mask): (4, 4), source -> template."""
    reg = require_open3d("ICP from the centroids matched").pipelines.registration
    start = np.eye(4)
    start[:3, 3] = template.get_center() - source.get_center()
    reach = 2.0 * float(np.linalg.norm(template.get_max_bound() - template.get_min_bound()))
    result = reg.registration_icp(
        source,
        template,
        reach,
        start,
        reg.TransformationEstimationPointToPoint(),
        reg.ICPConvergenceCriteria(max_iteration=iterations),
    )
    return np.asarray(result.transformation)
