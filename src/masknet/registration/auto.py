"""``method="auto"``, the default: a fast path, checked, escalated to ``robust`` when needed.

1. **Fast path.** One round of the paper's Mask-ICP (MaskNet's template mask, the source
   centroid onto the masked template's centroid, 10 iterations of ICP), then ICP with
   pairs cut at ``max_correspondence_distance`` (1.5 template spacings): a geometric inlier mask, once the
   clouds are close (the nearest-neighbour refinement rule).
2. **Check.** On even subsets of the clouds
   (:func:`masknet.registration.prepared.prepare_pair`), the fit of the result: the share of
   the source's surface points within 1.5 template spacings of the template
   (:func:`masknet.registration.prepared.pose_fit`). Stray outliers do not count: points
   without two others within 2 template spacings, and points beside a surface (no other
   point within 1.5 spacings, off their neighbours' plane), each test unless it drops over
   5% of the points (:func:`masknet.registration.prepared.check_points`).
   A correct result fits at least ``accept_fitness``; a result stopped at a wrong pose
   fits less.
3. **Escalation.** Below that, the coarse-to-fine pipeline of ``method="robust"``
   (:mod:`masknet.registration.robust.search`) runs, and its fast path's result takes part as one
   more hypothesis (it wins if it fits best).

``info["path"]`` says which ran (``"fast"``, or ``"robust/correspondences"`` and
``"robust/search"``), and ``info["escalated_fitness"]`` the fast path's fit that sent it on
(NaN when it did not).
"""

from __future__ import annotations

import time

import numpy as np

from masknet.geometry.clouds import MIN_POINTS
from masknet.geometry.knn import cloud_tree
from masknet.geometry.sampling import spread_labels
from masknet.geometry.se3 import transform_points
from masknet.models.masknet import MaskNet
from masknet.models.two_sided import TwoSidedMaskNet
from masknet.registration.backends.base import MaskModels, PipelineRun
from masknet.registration.fit import FIT_SPACINGS, PoseFit, pose_fit
from masknet.registration.hypotheses import rotation_between_deg
from masknet.registration.icp import icp
from masknet.registration.options import ICPCriteria, RobustOptions
from masknet.registration.prepared import (
    check_points,
    prepare_pair,
)
from masknet.registration.robust import NetworkMasks, pipeline_run
from masknet.registration.robust.search import REFINE_TOLERANCE, coarse_to_fine
from masknet.registration.rounds import mask_and_register

__all__ = ["auto_register"]


def auto_register(
    template: np.ndarray,
    source: np.ndarray,
    template_net: np.ndarray,
    source_net: np.ndarray,
    models: MaskModels,
    options: RobustOptions,
    times: dict[str, float],
    precision: str = "auto",
) -> PipelineRun:
    """The pipeline of the module docstring for template (B, N, 3) and source (B, M, 3),
    float64, pair by pair, at full resolution; the networks see template_net (B, n, 3) and
    source_net (B, m, 3), the clouds sampled to their size. ``models.first`` masks the fast
    path (None: plain ICP), ``models.search`` the escalation (None: no mask). Masks are over
    the full clouds. The method table's adapter of ``"auto"``."""
    model, search_model = models
    runs = []
    for b in range(template.shape[0]):
        nets = (template_net[b : b + 1], source_net[b : b + 1])
        runs.append(
            _one(template[b], source[b], nets, model, search_model, options, times, precision)
        )
    info = {key: np.concatenate([r.info[key] for r in runs]) for key in runs[0].info}

    def stacked(parts: list) -> np.ndarray | None:
        return None if any(p is None for p in parts) else np.concatenate(parts)

    return PipelineRun(
        np.concatenate([r.transform for r in runs]),
        stacked([r.mask for r in runs]),
        stacked([r.source_mask for r in runs]),
        info,
    )


def _one(
    template: np.ndarray,
    source: np.ndarray,
    nets: tuple[np.ndarray, np.ndarray],
    model: MaskNet | TwoSidedMaskNet | None,
    search_model: TwoSidedMaskNet | None,
    options: RobustOptions,
    times: dict[str, float],
    precision: str,
) -> PipelineRun:
    """One pair: template (N, 3), source (M, 3); ``nets`` the (1, n, 3) and (1, m, 3)
    clouds the networks see."""
    icp_options = ICPCriteria()  # the paper's Mask-ICP: 10 iterations, all pairs
    fast = mask_and_register(*nets, "icp", model, 1, icp_options, times, precision=precision)
    tic = time.perf_counter()
    prepared = prepare_pair(template, source, options.fine_points)
    fine_template, tree, spacing, fine, surface = prepared[:5]
    source_mask = None
    if fast.source_mask is not None:  # a two-sided network: its kept points, spread
        source_mask = spread_labels(source, nets[1][0], fast.source_mask[0])
        kept_fine = spread_labels(fine, nets[1][0], fast.source_mask[0]) & surface
        surface = kept_fine if kept_fine.sum() >= MIN_POINTS else surface
    kept = fine[surface]
    # The check's points among those kept (a two-sided network's mask narrows both).
    checked = fine[check_points(surface, prepared.strict, prepared.attached)]
    sol = icp(
        fine_template,
        kept,
        fast.transform[0],
        options.inlier_iterations,
        REFINE_TOLERANCE,
        max_correspondence_distance=options.cut(spacing),
        template_tree=tree,
    )
    transform = sol.transform[0]
    fit = pose_fit(tree, kept, transform, FIT_SPACINGS * spacing)
    if len(checked) >= 3:  # the verdict counts only points with neighbours enough
        right = pose_fit(tree, checked, transform, FIT_SPACINGS * spacing).fitness
    else:
        right = fit.fitness
    times["fast"] = times.get("fast", 0.0) + time.perf_counter() - tic
    if right >= options.accept_fitness:
        mask = None
        if model is not None:  # the template points the moved source covers
            moved = transform_points(transform, kept)
            mask = (cloud_tree(moved).query(template, k=1)[0] <= FIT_SPACINGS * spacing)[None]
        info = _info("fast", fit, np.nan)
        return PipelineRun(
            transform[None], mask, None if source_mask is None else source_mask[None], info
        )
    if search_model is not None and search_model is model and fast.mask is not None:
        # The fast path's network is the search's: its masks serve again.
        search_model = _GivenMasks(fast.mask[0], fast.source_mask)
    masks = None
    if search_model is not None:
        masks = NetworkMasks(search_model, nets[0][0], nets[1][0], precision)
    run = pipeline_run([coarse_to_fine(template, source, masks, options, times, prepared)])
    if run.info["score"][0] < fit.score:  # the fast path's pose fits better after all
        info = _info("fast", fit, right)
        # The search's answers that fit as well and lie elsewhere make this one ambiguous.
        others = [(run.transform[0], run.info["fitness"][0], run.info["score"][0])]
        if np.isfinite(run.info["runner_up"][0]).all():
            others.append(
                (
                    run.info["runner_up"][0],
                    run.info["runner_up_fitness"][0],
                    run.info["runner_up_score"][0],
                )
            )
        for other, other_fitness, other_score in others:
            apart = rotation_between_deg(other, transform) >= options.distinct_deg
            if apart and other_score >= fit.score - options.ambiguity_margin:
                info["ambiguous"] = np.array([True])
                info["runner_up"] = other[None].copy()
                info["runner_up_fitness"] = np.array([other_fitness])
                info["runner_up_score"] = np.array([other_score])
                break
        return PipelineRun(transform[None], run.mask, run.source_mask, info)
    info = dict(run.info)
    info["path"] = np.array([f"robust/{run.info['path'][0]}"])
    info["escalated_fitness"] = np.array([right])
    return PipelineRun(run.transform, run.mask, run.source_mask, info)


def _info(path: str, fit: PoseFit, escalated: float) -> dict[str, np.ndarray]:
    """The info of a fast-path result, with the keys of the robust pipeline's."""
    return {
        "path": np.array([path]),
        "source": np.array(["fast"]),
        "fitness": np.array([fit.fitness]),
        "inlier_rmse": np.array([fit.rmse]),
        "ambiguous": np.array([False]),
        "runner_up_fitness": np.array([np.nan]),
        "score": np.array([fit.score]),
        "runner_up_score": np.array([np.nan]),
        "hypotheses": np.array([1]),
        "runner_up": np.full((1, 4, 4), np.nan),
        "escalated_fitness": np.array([escalated]),
    }


class _GivenMasks:
    """Masks already predicted, answering the mask protocol: template (n,) and source
    (1, m) or None, for the clouds they were predicted on."""

    def __init__(self, mask: np.ndarray, source_mask: np.ndarray | None) -> None:
        self.masks = mask, None if source_mask is None else source_mask[0]

    def predict_masks(
        self, template: np.ndarray, source: np.ndarray, **_: object
    ) -> tuple[np.ndarray, np.ndarray | None]:
        return self.masks
