"""Point-to-point ICP: one function, two branches with one set of rules.

Each iteration moves the source by the current estimate, pairs every source point with
its nearest template point, drops pairs farther apart than ``max_correspondence_distance``
and ``source_valid`` points, solves the Kabsch problem and composes the update on the left.

- **numpy, one pair** ((N, 3) and (M, 3)): a KD-tree built once (or given: small_gicp's
  ``align(target, source, target_tree)``), numpy float64 around one query per iteration.
  A single pair of a thousand points is dominated by torch's per-call cost; this is what
  :func:`masknet.register` runs on the CPU.
- **torch, a batch** ((B, N, 3) and (B, M, 3), CPU or GPU): batched k-NN and solves, for
  many pairs at once and for the GPU.

Both stop a pair once its inlier RMSE changes by at most ``relative_rmse`` of itself (or
falls below 1e-7 of the template's size), and report ``fitness`` and ``inlier_rmse`` with
Open3D's definitions (Open3D's ``transformation`` is ``transform`` here). The transform maps
source points into the template frame, as everywhere in masknet (:mod:`masknet.geometry.se3`).
:func:`icp_from_starts` runs many starts of one pair at once, a global search's hypotheses.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import torch
from torch import Tensor

from masknet.geometry.align import rigid_align, rigid_transforms_numpy
from masknet.geometry.knn import KDTreeIndex, cloud_tree, knn_points
from masknet.geometry.se3 import make_transform, so3_exp, transform_points

__all__ = ["ICPSolution", "icp", "icp_from_starts"]

# Exact fits shrink the error geometrically, never slowing in relative terms: below
# (1e-7 of the template's size)^2 a pair has converged too (also unit-free).
_FLOOR = 1e-14


class ICPSolution(NamedTuple):
    """Result of :func:`icp` (and of :func:`masknet.registration.solvers.open3d_icp.open3d_icp`),
    numpy for numpy input, torch for torch input.

    transform: (B, 4, 4) source -> template, ``template ~= source @ R.T + t`` (B = 1 for a
        numpy pair).
    converged: (B,) bool, True where the stopping rule was met before ``max_iterations``.
    iterations: (B,) int64, updates applied (-1 where the backend does not report it).
    fitness: (B,) fraction of source points in use with a template point within
        ``max_correspondence_distance`` at the final transform (Open3D's definition).
    inlier_rmse: (B,) root mean square distance over those inlier pairs (0 when there
        are none; Open3D's definition).
    """

    transform: Any
    converged: Any
    iterations: Any
    fitness: Any
    inlier_rmse: Any


def _check(max_iterations: int, relative_rmse: float, max_distance: float | None) -> None:
    if max_iterations < 0:
        raise ValueError(f"max_iterations must be >= 0, got {max_iterations}")
    if not relative_rmse >= 0:
        raise ValueError(f"relative_rmse must be >= 0, got {relative_rmse}")
    if max_distance is not None and not max_distance > 0:
        raise ValueError(f"max_correspondence_distance must be positive, got {max_distance}")


def _settled(prev_mse: Any, mse: Any, relative_rmse: float, floor: Any) -> Any:
    """The stopping rule, for floats or tensors: the RMSE changed by at most
    ``relative_rmse`` of itself, or the error is below the floor."""
    change = abs(prev_mse**0.5 - mse**0.5)
    return (change <= relative_rmse * prev_mse**0.5) | (mse <= floor)


def icp(
    template: np.ndarray | Tensor,
    source: np.ndarray | Tensor,
    init: np.ndarray | Tensor | None = None,
    max_iterations: int = 10,
    relative_rmse: float = 5e-7,
    max_correspondence_distance: float | None = None,
    template_valid: Tensor | None = None,
    source_valid: np.ndarray | Tensor | None = None,
    template_tree: Any | None = None,
    template_normals: np.ndarray | None = None,
) -> ICPSolution:
    """Point-to-point ICP (point-to-plane given normals): moves ``source`` onto ``template``.

    Arguments in masknet's order, ``(template, source)``, as :func:`masknet.register`.

    Args:
        template: (N, 3) float64 numpy (one pair), or (B, N, 3) tensor.
        source: (M, 3) numpy, or (B, M, 3) tensor of the template's dtype and device.
        init: (4, 4) or (B, 4, 4) initial source -> template transform; None: identity.
        max_iterations: most updates per pair (0 just evaluates ``init``).
        relative_rmse: a pair stops, converged, once its inlier RMSE changes by at most
            this fraction of itself in one iteration (relative, unlike Open3D's, so that
            the result does not depend on the unit).
        max_correspondence_distance: pairs farther apart are not used (and do not count
            towards fitness); None keeps every pair.
        template_valid: (B, N) bool, torch only; template points marked False are never
            matched (fixed shapes for masked, batched templates).
        source_valid: (M,) or (B, M) bool; source points marked False take no part, in
            the solve or the fitness (fixed shapes for masked, batched sources).
        template_tree: numpy only: a KD-tree of ``template`` from
            :func:`masknet.geometry.knn.cloud_tree`, built once for many calls.
        template_normals: numpy only: (N, 3) unit normals of ``template``
            (:func:`masknet.geometry.normals.estimate_normals`); then each update minimises
            the distances of the source points to the template's tangent planes
            (point-to-plane, linearised), which does not pull a source sampled apart from
            the template onto its sample points. ``fitness`` and ``inlier_rmse`` stay
            point-to-point.

    Returns:
        ICPSolution: numpy float64 for numpy input; for tensors, ``transform``,
        ``fitness`` and ``inlier_rmse`` in the dtype of ``source`` (the iteration itself
        composes in float64). A pair with no inlier stops at once with the identity
        update and ``converged`` False.

    Raises:
        ValueError: bad shapes, dtypes or options.
    """
    _check(max_iterations, relative_rmse, max_correspondence_distance)
    if isinstance(template, np.ndarray) or isinstance(source, np.ndarray):
        return _icp_pair(
            np.asarray(template, dtype=np.float64),
            np.asarray(source, dtype=np.float64),
            init,
            max_iterations,
            relative_rmse,
            max_correspondence_distance,
            source_valid,
            template_tree,
            template_normals,
        )
    if template_normals is not None:
        raise ValueError("template_normals (point-to-plane) is for numpy pairs")
    return _icp_batch(
        template,
        source,
        init,
        max_iterations,
        relative_rmse,
        max_correspondence_distance,
        template_valid,
        source_valid,
    )


def _icp_pair(
    template: np.ndarray,
    source: np.ndarray,
    init: np.ndarray | None,
    max_iterations: int,
    relative_rmse: float,
    max_distance: float | None,
    source_valid: np.ndarray | None,
    tree: Any | None,
    normals: np.ndarray | None = None,
) -> ICPSolution:
    """:func:`icp` for one numpy pair: template (N, 3), source (M, 3)."""
    if template.ndim != 2 or source.ndim != 2 or template.shape[1] != 3 or source.shape[1] != 3:
        raise ValueError(
            f"expected template (N,3) and source (M,3), got {template.shape} and {source.shape}"
        )
    tree = cloud_tree(template) if tree is None else tree
    if source_valid is not None:
        source = source[np.asarray(source_valid, bool).reshape(-1)]
    floor = _FLOOR * float(((template - template.mean(0)) ** 2).sum(1).mean())
    limit = None if max_distance is None else max_distance**2
    transform = np.eye(4) if init is None else np.array(init, dtype=np.float64).reshape(4, 4)
    total = max(len(source), 1)

    if normals is not None and np.shape(normals) != template.shape:
        raise ValueError(f"template_normals must be {template.shape}, got {np.shape(normals)}")

    def match(tf: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, float, float]:
        """The source moved by ``tf``, its nearest template points, which of them are
        pairs (None: all), fitness and inlier MSE."""
        moved = transform_points(tf, source)
        d2, idx = tree.query(moved, k=1, sqr_dists=True)
        inlier = None if limit is None else d2 <= limit
        count = len(d2) if inlier is None else int(np.count_nonzero(inlier))
        if count == len(d2):  # every pair kept: no copies of the clouds
            inlier = None
        mse = float((d2 if inlier is None else d2[inlier]).sum()) / max(count, 1)
        return moved, idx, inlier, count / total, mse

    def update(moved: np.ndarray, idx: np.ndarray, inlier: np.ndarray | None) -> np.ndarray:
        if inlier is not None:
            moved, idx = moved[inlier], idx[inlier]
        if normals is None:
            return rigid_transforms_numpy(moved[None], template[idx][None])[0]
        return _point_to_plane_step(moved, template[idx], normals[idx])

    moved, idx, inlier, fitness, mse = match(transform)
    converged, iterations = False, 0
    for _ in range(max_iterations if fitness > 0 else 0):
        transform = update(moved, idx, inlier) @ transform
        iterations += 1
        previous = mse
        moved, idx, inlier, fitness, mse = match(transform)
        if fitness == 0:
            break
        if _settled(previous, mse, relative_rmse, floor):
            converged = True
            break
    return ICPSolution(
        transform[None],
        np.array([converged]),
        np.array([iterations], dtype=np.int64),
        np.array([fitness]),
        np.array([np.sqrt(mse)]),
    )


def _point_to_plane_step(source: np.ndarray, target: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """The (4, 4) rigid update that minimises sum(((R p + t - q) . n)^2) over pairs p
    (K, 3) -> q (K, 3) with normals n (K, 3), linearised in the rotation (small angles) and
    made exactly rigid by the exponential map; identity for a degenerate system."""
    a = np.concatenate([np.cross(source, normals), normals], axis=1)  # (K, 6)
    b = ((target - source) * normals).sum(1)
    try:
        x = np.linalg.solve(a.T @ a, a.T @ b)
    except np.linalg.LinAlgError:
        return np.eye(4)
    update = np.eye(4)
    update[:3, :3] = so3_exp(torch.from_numpy(x[:3])[None])[0].numpy()
    update[:3, 3] = x[3:]
    return update


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
    source_valid: Tensor | None,
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
    total = source.shape[1]
    if source_valid is not None:
        inlier = inlier & source_valid
        total = source_valid.sum(1).clamp_min(1)
    count = inlier.sum(1)
    mse = (d2 * inlier).sum(1) / count.clamp_min(1)
    return _Matches(moved, matched, inlier, count.double() / total, mse)


def _icp_batch(
    template: Tensor,
    source: Tensor,
    init: Tensor | None,
    max_iterations: int,
    relative_rmse: float,
    max_distance: float | None,
    template_valid: Tensor | None,
    source_valid: Tensor | None,
) -> ICPSolution:
    """:func:`icp` for a batch of tensors: template (B, N, 3), source (B, M, 3)."""
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
    b, device = source.shape[0], source.device
    if init is None:
        transform = torch.eye(4, dtype=torch.float64, device=device).repeat(b, 1, 1)
    else:
        init = torch.as_tensor(init)
        if init.shape not in ((4, 4), (b, 4, 4)):
            raise ValueError(f"init must be (4,4) or ({b},4,4), got {tuple(init.shape)}")
        transform = init.to(device=device, dtype=torch.float64).expand(b, 4, 4).clone()
    if source_valid is not None:
        source_valid = torch.as_tensor(source_valid, device=device)
        if source_valid.dtype != torch.bool or source_valid.shape != source.shape[:2]:
            raise ValueError(f"source_valid must be bool of shape {tuple(source.shape[:2])}")

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

    size2 = (template.double() - template.double().mean(1, keepdim=True)).square().sum(-1).mean(1)
    floor = _FLOOR * size2
    index = KDTreeIndex(template, template_valid) if device.type == "cpu" else None

    def match(tf: Tensor) -> _Matches:
        return _match(tf, template, source, max_distance, template_valid, source_valid, index)

    m = match(transform)
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
        m = match(transform)
        has_inliers = m.fitness > 0
        newly = ~done & has_inliers & _settled(prev_mse, m.mse, relative_rmse, floor)
        converged |= newly
        done |= newly | ~has_inliers
    return ICPSolution(
        transform.to(source.dtype),
        converged,
        iterations,
        m.fitness.to(source.dtype),
        m.mse.sqrt().to(source.dtype),
    )


def icp_from_starts(
    template_tree: Any,
    template: np.ndarray,
    source: np.ndarray,
    starts: np.ndarray,
    max_iterations: int = 10,
) -> np.ndarray:
    """Point-to-point ICP of source (M, 3) onto template (N, 3) from each of ``starts``
    (H, 4, 4) at once: one KD-tree query of all H moved copies and one batched solve per
    iteration, every pair used. Returns (H, 4, 4). ``template_tree``: from
    :func:`masknet.geometry.knn.cloud_tree`. A fixed number of iterations (no stopping
    rule): the hypotheses of a global search, scored afterwards."""
    transforms = np.array(starts, dtype=np.float64)
    h, m = len(transforms), len(source)
    for _ in range(max_iterations):
        moved = transform_points(transforms, source)
        _, idx = template_tree.query(moved.reshape(h * m, 3), k=1)
        matched = template[idx.astype(np.int64)].reshape(h, m, 3)
        transforms = rigid_transforms_numpy(moved, matched) @ transforms
    return transforms
