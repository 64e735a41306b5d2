"""Point-to-point ICP for one pair on the CPU: a KD-tree built once, numpy in float64.

The batched torch ICP (:func:`masknet.registration.icp.icp`) pays a fixed cost per
tensor operation that dominates a single pair of a thousand points; this loop runs
the same iteration with the same rules (correspondences, the pair cut-off, the
relative stopping rule and its floor, ``fitness`` and ``inlier_rmse``) in plain numpy
around one pykdtree search per iteration. :func:`masknet.registration.backends.run_icp`
picks it for single pairs on the CPU.
"""

from __future__ import annotations

import numpy as np
import torch

from masknet.geometry.align import rigid_transform_numpy, rigid_transforms_numpy
from masknet.registration.icp import ICPSolution

__all__ = ["icp_from_starts", "icp_single"]


def icp_single(
    template: np.ndarray,
    source: np.ndarray,
    init: np.ndarray | None = None,
    max_iterations: int = 10,
    tolerance: float = 1e-6,
    max_correspondence_distance: float | None = None,
    template_tree: object | None = None,
) -> ICPSolution:
    """ICP of source (M, 3) onto template (N, 3), both float64 numpy; ``init`` (4, 4).
    ``template_tree``: a pykdtree ``KDTree`` of ``template`` built once by the caller, for
    loops that align many sources or starts to one template (built here when None).

    Returns an :class:`ICPSolution` of batch 1 (torch tensors), as :func:`icp` does.
    """
    from pykdtree.kdtree import KDTree

    tree = KDTree(np.ascontiguousarray(template)) if template_tree is None else template_tree
    centred = template - template.mean(0)
    floor = 1e-14 * float((centred**2).sum(1).mean())
    limit = None if max_correspondence_distance is None else max_correspondence_distance**2
    transform = np.eye(4) if init is None else np.array(init, dtype=np.float64)

    def match(tf: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
        moved = source @ tf[:3, :3].T + tf[:3, 3]
        d2, idx = tree.query(moved, k=1, sqr_dists=True)
        matched = template[idx]
        inlier = np.ones(len(d2), bool) if limit is None else d2 <= limit
        count = int(inlier.sum())
        mse = float(d2[inlier].sum() / max(count, 1))
        return moved, matched, inlier, count / len(source), mse

    moved, matched, inlier, fitness, mse = match(transform)
    converged, iterations = False, 0
    done = fitness == 0
    for _ in range(max_iterations):
        if done:
            break
        transform = rigid_transform_numpy(moved[inlier], matched[inlier]) @ transform
        iterations += 1
        previous = mse
        moved, matched, inlier, fitness, mse = match(transform)
        if fitness == 0:
            break
        if abs(previous - mse) <= tolerance * previous or mse <= floor:
            converged = True
            break
    return ICPSolution(
        torch.from_numpy(transform[None]),
        torch.tensor([converged]),
        torch.tensor([iterations]),
        torch.tensor([fitness], dtype=torch.float64),
        torch.tensor([np.sqrt(mse)], dtype=torch.float64),
    )


def icp_from_starts(
    template_tree: object,
    template: np.ndarray,
    source: np.ndarray,
    starts: np.ndarray,
    max_iterations: int = 10,
) -> np.ndarray:
    """Point-to-point ICP of source (M, 3) onto template (N, 3) from each of ``starts``
    (H, 4, 4) at once: one KD-tree query of all H moved copies and one batched solve per
    iteration, every pair used. Returns (H, 4, 4). ``template_tree``: a pykdtree
    ``KDTree`` of ``template``. A fixed number of iterations (no stopping rule): the
    hypotheses of a global search, scored afterwards."""
    transforms = np.array(starts, dtype=np.float64)
    h, m = len(transforms), len(source)
    for _ in range(max_iterations):
        moved = source @ transforms[:, :3, :3].transpose(0, 2, 1) + transforms[:, None, :3, 3]
        _, idx = template_tree.query(moved.reshape(h * m, 3), k=1)
        matched = template[idx.astype(np.int64)].reshape(h, m, 3)
        transforms = rigid_transforms_numpy(moved, matched) @ transforms
    return transforms
