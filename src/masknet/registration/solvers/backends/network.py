"""Adapter of the learned registration networks (PointNetLK, DCP, PRNet, PCRNet, RPM-Net)."""

from __future__ import annotations

import numpy as np
import torch

from masknet.geometry.clouds import unit_radius
from masknet.geometry.sampling import farthest_point_sample
from masknet.registration.solvers.backends.base import (
    BackendRun,
    check_template_points,
    keep_source_points,
    usable,
)
from masknet.registration.terms.options import NetworkOptions, PointNetLKOptions

__all__ = ["run_network"]


@torch.inference_mode()
def run_network(
    template: np.ndarray,
    source: np.ndarray,
    mask: np.ndarray | None,
    source_mask: np.ndarray | None,
    options: NetworkOptions,
) -> BackendRun:
    """A learned network (``options.network``) on each pair's template points in use (all,
    or the masked ones) and kept source points. template (B, N, 3), source (B, M, 3), mask
    (B, N) and source_mask (B, M) bool or None."""
    keep = usable(source_mask)
    if keep is not None and not keep.all() and len(source) > 1:
        # A network weighs every point it is given (attention, soft matches): a batch
        # would have to repeat kept points to keep one shape, so it runs pair by pair.
        return _concatenated(
            [
                run_network(
                    template[i : i + 1],
                    source[i : i + 1, keep[i]],
                    None if mask is None else mask[i : i + 1],
                    None,
                    options,
                )
                for i in range(len(source))
            ]
        )
    source = keep_source_points(source, keep)  # one pair: exactly its kept points
    if mask is None or len(set(mask.sum(1).tolist())) == 1:
        # Every pair keeps the same number of points (top-k masks): one batched call.
        index = None if mask is None else np.stack([np.flatnonzero(m) for m in mask])
        return _network_batch(template, source, index, options)
    return _concatenated(  # threshold masks: sizes differ, so pair by pair
        [
            _network_batch(template[i : i + 1], source[i : i + 1], idx[None], options)
            for i, idx in enumerate(np.flatnonzero(m) for m in mask)
        ]
    )


def _concatenated(parts: list[BackendRun]) -> BackendRun:
    """Runs of single pairs as one run of the batch."""
    inliers = [p.correspondence_inliers for p in parts]
    return BackendRun(
        np.concatenate([p.transform for p in parts]),
        {key: np.concatenate([p.info[key] for p in parts]) for key in parts[0].info},
        None if inliers[0] is None else np.concatenate(inliers),
    )


def _network_batch(
    template: np.ndarray,
    source: np.ndarray,
    index: np.ndarray | None,
    options: NetworkOptions,
) -> BackendRun:
    """Run ``network`` on template[:, index] (B, K, 3) and source (B, M, 3), scaled to unit
    radius; clouds above the network's ``input_points`` are farthest-point sampled first."""
    b = template.shape[0]
    index = (
        np.broadcast_to(np.arange(template.shape[1]), template.shape[:2])
        if index is None
        else index
    )
    check_template_points(index.shape[1], rule="the mask given to the network")
    network = options.network
    limit = getattr(network, "config", {}).get("input_points")
    n_used, m = index.shape[1], source.shape[1]
    if limit and (n_used > limit or m > limit):
        n_keep = min(n_used, limit)
        m_keep = min(m, limit, max(3, round(m * n_keep / n_used)))  # same overlap ratio
        index = np.stack(
            [
                index[i][farthest_point_sample(template[i, index[i]], n_keep).indices]
                for i in range(b)
            ]
        )
        source = np.stack(
            [source[i][farthest_point_sample(source[i], m_keep).indices] for i in range(b)]
        )
    tpl = torch.from_numpy(template).float()
    # The networks saw unit-radius shapes: scale each pair by its template's radius.
    radius = unit_radius(tpl)[:, None, None]
    used = torch.gather(tpl, 1, torch.from_numpy(np.array(index))[..., None].expand(-1, -1, 3))
    device = next(network.parameters()).device
    kwargs = {"max_iterations": options.max_iterations}
    if isinstance(options, PointNetLKOptions):
        kwargs["tolerance"] = options.tolerance
    was_training = network.training
    network.eval()  # e.g. PRNet samples Gumbel noise in training mode
    try:
        solution = network(
            (used / radius).to(device),
            (torch.from_numpy(source).float() / radius).to(device),
            **kwargs,
        )
    finally:
        network.train(was_training)
    transform = solution.transform.double().cpu().numpy()
    transform[:, :3, 3] *= radius[:, 0].double().numpy()
    info = {"iterations": solution.iterations.cpu().numpy()}
    if hasattr(solution, "converged"):  # PointNetLK
        info["converged"] = solution.converged.cpu().numpy()
        info["feature_residual"] = solution.residual.double().cpu().numpy()
    inliers = None
    weight = getattr(solution, "template_weight", None)
    if weight is not None:
        inliers = np.zeros(template.shape[:2], bool)
        np.put_along_axis(inliers, index, (weight >= 0.5).cpu().numpy(), axis=1)
    return BackendRun(transform, info, inliers)
