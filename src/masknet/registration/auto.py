"""``method="auto"``, the default: a fast path, checked, escalated to ``robust`` when needed.

1. **Fast path.** One round of the paper's Mask-ICP (MaskNet's template mask, the source
   centroid onto the masked template's centroid, ``max_iterations`` of ICP), then ICP with
   pairs cut at ``inlier_distance`` template spacings: a geometric inlier mask, once the
   clouds are close (the nearest-neighbour refinement rule).
2. **Check.** The fit of the result: the share of the source's non-isolated points within
   1.5 template spacings of the template (:func:`masknet.registration.coarse.pose_fit`).
   A correct result fits at least ``accept_fitness``; a result stopped at a wrong pose
   fits less.
3. **Escalation.** Below that, the coarse-to-fine pipeline of ``method="robust"``
   (:mod:`masknet.registration.coarse`) runs, and its fast path's result takes part as one
   more hypothesis (it wins if it fits best).

``info["path"]`` says which ran (``"fast"``, or ``"robust/correspondences"`` and
``"robust/search"``), and ``info["escalated_fitness"]`` the fast path's fit that sent it on
(NaN when it did not).
"""

from __future__ import annotations

import time

import numpy as np
from pykdtree.kdtree import KDTree

from masknet.models.masknet import MaskNet
from masknet.models.two_sided import TwoSidedMaskNet
from masknet.registration.coarse import (
    FIT_SPACINGS,
    SURFACE_SPACINGS,
    isolated_free,
    nonzero_spacing,
    pose_fit,
)
from masknet.registration.icp_tree import icp_single
from masknet.registration.options import RobustOptions
from masknet.registration.robust import RobustRun, robust_register
from masknet.registration.rounds import mask_and_register

__all__ = ["auto_register"]


def auto_register(
    template: np.ndarray,
    source: np.ndarray,
    model: MaskNet | TwoSidedMaskNet | None,
    search_model: TwoSidedMaskNet | None,
    options: RobustOptions,
    times: dict[str, float],
    precision: str = "auto",
) -> RobustRun:
    """The pipeline of the module docstring for template (B, N, 3) and source (B, M, 3),
    float64, pair by pair. ``model`` masks the fast path (None: plain ICP), ``search_model``
    the escalation (None: no mask)."""
    options.check()
    runs = [
        _one(template[b : b + 1], source[b : b + 1], model, search_model, options, times, precision)
        for b in range(template.shape[0])
    ]
    info = {key: np.concatenate([r.info[key] for r in runs]) for key in runs[0].info}

    def stacked(parts: list) -> np.ndarray | None:
        return None if any(p is None for p in parts) else np.concatenate(parts)

    return RobustRun(
        np.concatenate([r.transform for r in runs]),
        stacked([r.mask for r in runs]),
        stacked([r.source_mask for r in runs]),
        info,
    )


def _one(
    template: np.ndarray,
    source: np.ndarray,
    model: MaskNet | TwoSidedMaskNet | None,
    search_model: TwoSidedMaskNet | None,
    options: RobustOptions,
    times: dict[str, float],
    precision: str,
) -> RobustRun:
    """One pair (B = 1)."""
    tic = time.perf_counter()
    tpl, src = template[0], source[0]
    tree = KDTree(tpl)
    spacing = nonzero_spacing(tree, tpl)
    surface = isolated_free(src, SURFACE_SPACINGS * spacing)
    icp_options = {"max_iterations": options.max_iterations}
    fast = mask_and_register(
        template, source, "icp", model, 1, icp_options, times, precision=precision
    )
    tic = time.perf_counter()
    kept = src[surface]
    if fast.source_mask is not None and (fast.source_mask[0] & surface).sum() >= 3:
        kept = src[fast.source_mask[0] & surface]
    sol = icp_single(
        tpl,
        kept,
        fast.transform[0],
        options.inlier_iterations,
        max_correspondence_distance=options.inlier_distance * spacing,
        template_tree=tree,
    )
    transform = sol.transform[0].numpy()
    fit = pose_fit(tree, kept, transform, FIT_SPACINGS * spacing)
    times["fast"] = times.get("fast", 0.0) + time.perf_counter() - tic
    if fit.fitness >= options.accept_fitness:
        moved = kept @ transform[:3, :3].T + transform[:3, 3]
        mask = None
        if model is not None:  # the template points the moved source covers
            mask = (KDTree(moved).query(tpl, k=1)[0] <= FIT_SPACINGS * spacing)[None]
        info = _info("fast", fit.fitness, fit.rmse, np.nan)
        return RobustRun(transform[None], mask, fast.source_mask, info)
    run = robust_register(template, source, search_model, options, times, precision)
    if run.info["fitness"][0] < fit.fitness:  # the fast path's pose fits better after all
        info = _info("fast", fit.fitness, fit.rmse, fit.fitness)
        return RobustRun(transform[None], run.mask, run.source_mask, info)
    info = {key: value for key, value in run.info.items()}
    info["path"] = np.array([f"robust/{run.info['path'][0]}"])
    info["escalated_fitness"] = np.array([fit.fitness])
    return RobustRun(run.transform, run.mask, run.source_mask, info)


def _info(path: str, fitness: float, rmse: float, escalated: float) -> dict[str, np.ndarray]:
    """The info of a fast-path result, with the keys of the robust pipeline's."""
    return {
        "path": np.array([path]),
        "source": np.array(["fast"]),
        "fitness": np.array([fitness]),
        "inlier_rmse": np.array([rmse]),
        "ambiguous": np.array([False]),
        "runner_up_fitness": np.array([np.nan]),
        "hypotheses": np.array([1]),
        "runner_up": np.full((1, 4, 4), np.nan),
        "escalated_fitness": np.array([escalated]),
    }
