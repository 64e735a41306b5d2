"""Batched point-to-point ICP in torch (CPU or GPU, on whatever device the inputs are).

Each iteration moves the source by the current estimate, pairs every source point
with its nearest template point (:func:`masknet.geometry.knn_points`), drops pairs
farther apart than ``max_correspondence_distance``, solves the weighted Kabsch
problem (:func:`masknet.geometry.rigid_align`) and composes the update on the left.

Names and definitions follow Open3D's ``registration_icp`` where the two overlap
(``fitness``, ``inlier_rmse``; Open3D's ``transformation`` is ``transform`` here).
The transform maps source points into the template frame, as everywhere in masknet
(:mod:`masknet.geometry.se3`).
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from masknet.geometry.align import rigid_align
from masknet.geometry.knn import KDTreeIndex, knn_points
from masknet.geometry.se3 import make_transform, transform_points

__all__ = ["ICPSolution", "icp"]


class ICPSolution(NamedTuple):
    """Result of :func:`icp` (and of :func:`masknet.registration.open3d_icp`).

    transform: (B, 4, 4) source -> template, ``template ~= source @ R.T + t``.
    converged: (B,) bool, True where the relative change in mean squared error fell
        to the tolerance before ``max_iterations``.
    iterations: (B,) int64, updates applied (-1 where the backend does not report it).
    fitness: (B,) fraction of source points with a template point within
        ``max_correspondence_distance`` at the final transform (Open3D's definition).
    inlier_rmse: (B,) root mean square distance over those inlier pairs (0 when
        there are none; Open3D's definition).
    """

    transform: Tensor
    converged: Tensor
    iterations: Tensor
    fitness: Tensor
    inlier_rmse: Tensor


class _Matches(NamedTuple):
    moved: Tensor  # (B, M, 3) source under the current transform, float64
    matched: Tensor  # (B, M, 3) nearest valid template point, float64
    inlier: Tensor  # (B, M) bool
    fitness: Tensor  # (B,) float64
    mse: Tensor  # (B,) float64, mean squared distance over inliers (0 if none)


def _match(
    transform: Tensor,
    template: Tensor,
    source: Tensor,
    max_distance: float | None,
    template_valid: Tensor | None,
    index: KDTreeIndex | None = None,
) -> _Matches:
    """Nearest-neighbour pairs for ``source`` moved by ``transform`` (B, 4, 4) float64;
    ``index``: the template's KD-trees, built once per call on the CPU."""
    moved = transform_points(transform.to(source.dtype), source)
    if index is not None:
        idx = index.query(moved, 1).idx[..., 0]
    else:
        idx = knn_points(moved, template, 1, reference_valid=template_valid).idx[..., 0]  # (B, M)
    found = idx >= 0
    matched = torch.gather(template, 1, idx.clamp_min(0)[..., None].expand(-1, -1, 3)).double()
    moved = moved.double()
    d2 = (moved - matched).square().sum(-1)  # exact, unlike the k-NN's expanded form
    inlier = found if max_distance is None else found & (d2 <= max_distance**2)
    count = inlier.sum(1)
    mse = (d2 * inlier).sum(1) / count.clamp_min(1)
    return _Matches(moved, matched, inlier, count.double() / source.shape[1], mse)


def icp(
    template: Tensor,
    source: Tensor,
    init: Tensor | None = None,
    max_iterations: int = 10,
    tolerance: float = 1e-6,
    max_correspondence_distance: float | None = None,
    template_valid: Tensor | None = None,
) -> ICPSolution:
    """Point-to-point ICP for a batch of pairs: moves ``source`` onto ``template``.

    Arguments in masknet's order, ``(template, source)``, as :func:`masknet.register`.

    Args:
        template: (B, N, 3) points to move the source onto.
        source: (B, M, 3) points to move (same dtype and device as the template).
        init: (B, 4, 4) or (4, 4) initial source -> template transform; None is the
            identity.
        max_iterations: most updates per pair (0 just evaluates ``init``).
        tolerance: a pair stops, converged, once its mean squared inlier distance
            changes by at most this fraction of itself in one iteration (relative, as
            Open3D's ``relative_rmse``, so the result does not depend on the unit).
        max_correspondence_distance: pairs farther apart are not used (and do not
            count towards fitness); None keeps every pair.
        template_valid: (B, N) bool; template points marked False are never matched
            (fixed shapes for masked, batched templates).

    Returns:
        ICPSolution; ``transform``, ``fitness`` and ``inlier_rmse`` in the dtype of
        ``source`` (the iteration itself composes in float64). A pair with no
        inlier stops at once with the identity update and ``converged`` False.
    """
    if (
        template.dim() != 3
        or source.dim() != 3
        or template.shape[-1] != 3
        or source.shape[-1] != 3
        or template.shape[0] != source.shape[0]
    ):
        raise ValueError(
            f"expected template (B,N,3) and source (B,M,3), got {tuple(template.shape)} "
            f"and {tuple(source.shape)}"
        )
    if not source.is_floating_point() or template.dtype != source.dtype:
        raise ValueError(
            f"template and source must share a floating dtype, got {template.dtype} "
            f"and {source.dtype}"
        )
    if max_iterations < 0:
        raise ValueError(f"max_iterations must be >= 0, got {max_iterations}")
    if max_correspondence_distance is not None and not max_correspondence_distance > 0:
        raise ValueError(
            f"max_correspondence_distance must be positive, got {max_correspondence_distance}"
        )
    b, device = source.shape[0], source.device
    if init is None:
        transform = torch.eye(4, dtype=torch.float64, device=device).repeat(b, 1, 1)
    else:
        if init.shape not in ((4, 4), (b, 4, 4)):
            raise ValueError(f"init must be (4,4) or ({b},4,4), got {tuple(init.shape)}")
        transform = init.to(device=device, dtype=torch.float64).expand(b, 4, 4).clone()

    if (
        template_valid is not None
        and template_valid.dtype == torch.bool
        and template_valid.shape == template.shape[:2]
    ):  # (anything else is left to knn_points to reject)
        counts = template_valid.sum(1)
        if int(counts[0]) > 0 and bool((counts == counts[0]).all()):
            # Equal counts (top-k masks): gather the points in use once, so that every
            # iteration searches K points instead of N and skips the masking.
            template = template[template_valid].view(b, int(counts[0]), 3)
            template_valid = None

    # Exact fits shrink the error geometrically, never slowing in relative terms: below
    # (1e-7 of the template's size)^2 a pair has converged too (also unit-free).
    size2 = (template.double() - template.double().mean(1, keepdim=True)).square().sum(-1).mean(1)
    floor = 1e-14 * size2
    index = (
        KDTreeIndex(template, template_valid)
        if device.type == "cpu" and template.shape[-1] == 3
        else None
    )
    m = _match(transform, template, source, max_correspondence_distance, template_valid, index)
    converged = torch.zeros(b, dtype=torch.bool, device=device)
    iterations = torch.zeros(b, dtype=torch.int64, device=device)
    done = m.fitness == 0
    for _ in range(max_iterations):
        if bool(done.all()):
            break
        rot, trans = rigid_align(m.moved, m.matched, m.inlier.double())
        update = make_transform(rot, trans) @ transform
        transform = torch.where(done[:, None, None], transform, update)
        iterations += (~done).long()
        prev_mse = m.mse
        m = _match(transform, template, source, max_correspondence_distance, template_valid, index)
        has_inliers = m.fitness > 0
        # Relative, so that a cloud in millimetres stops where the same cloud in metres does.
        settled = ((prev_mse - m.mse).abs() <= tolerance * prev_mse) | (m.mse <= floor)
        newly = ~done & has_inliers & settled
        converged |= newly
        done |= newly | ~has_inliers
    return ICPSolution(
        transform.to(source.dtype),
        converged,
        iterations,
        m.fitness.to(source.dtype),
        m.mse.sqrt().to(source.dtype),
    )
