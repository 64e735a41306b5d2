"""The rounds of Mask-X: {mask -> initialise -> register -> move the source}, batched.

:func:`masknet.register` runs them once per call; the default's fast path runs one
round (:mod:`masknet.registration.stages.auto`). Everything here is numpy float64 in the call's
frame; only the networks' own calls hold tensors.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from masknet._moved import moved_names
from masknet.geometry.se3 import transform_points
from masknet.registration.judge import fit
from masknet.registration.solvers.backends.base import check_template_points, usable
from masknet.registration.stages.refinement import Refiner
from masknet.registration.terms.methods import adapter
from masknet.registration.terms.result import Solution

__all__ = ["initial_transform", "mask_and_register"]


def mask_and_register(
    template: np.ndarray,
    source: np.ndarray,
    method: str,
    model: Any | None,
    iterations: int,
    options: Any,
    times: dict[str, float],
    k: int | None = None,
    threshold: float | None = None,
    precision: str = "auto",
    init: str = "centroid",
    start: np.ndarray | None = None,
    refiner: Refiner | None = None,
) -> Solution:
    """``iterations`` rounds on template (B, N, 3) and source (B, M, 3), float64.

    ``model``: a mask network (``predict_masks(template, source) -> (template mask,
    source mask | None)``), or None for plain X. ``options``: the method's typed options.
    ``start`` (B, 4, 4) is the transform the first round starts from (identity by
    default). ``refiner`` (see :mod:`masknet.registration.stages.refinement`) masks both clouds
    in rounds >= 2, on the pair as the previous round left it, and those rounds start from
    that pose (no centroid shift); a pair whose round fits worse than its start by more
    than ``FIT_SLACK`` (:class:`RoundFits`) keeps its start and stops there, as the
    default's rounds do; after the last round the refiner masks the pair once more, at
    the pose reached. None runs ``model`` in every round (the paper's loop, each round
    starting with ``init``). Without a model (plain X), rounds >= 2 start from the pose
    reached. Seconds spent are added to ``times["mask"]`` and ``times["register"]``.
    """
    run_method = adapter(method)
    b = template.shape[0]
    total = np.broadcast_to(np.eye(4), (b, 4, 4)).copy() if start is None else start.copy()
    rounds: list[np.ndarray] = []
    mask = source_mask = None
    run = None
    fits = fit.RoundFits(template, source) if refiner is not None and iterations > 1 else None
    for round_index in range(iterations):
        moved = transform_points(total, source)
        refining = refiner is not None and round_index > 0
        if refining or model is not None:
            tic = time.perf_counter()
            if refining:
                mask, source_mask = refiner.predict_masks(template, moved)
            else:
                mask, source_mask = model.predict_masks(
                    template, moved, k=k, threshold=threshold, precision=precision
                )
            times["mask"] += time.perf_counter() - tic
            if mask is not None and refining:
                check_template_points(
                    int(mask.sum(-1).min()),
                    rule=f"the refiner's mask in round {round_index + 1}; the clouds may not "
                    "overlap at the pose reached, refine_masks=None runs plain rounds",
                )
            elif mask is not None:
                check_template_points(int(mask.sum(-1).min()), k=k, threshold=threshold)
        tic = time.perf_counter()
        # Later rounds start where the last one ended; only the paper's loop (the
        # network again in every round) re-centres, as it always did.
        restart = round_index > 0 and (refiner is not None or model is None)
        start_tf = initial_transform(
            "identity" if restart else init, template, moved, mask, source_mask
        )
        run = run_method(template, transform_points(start_tf, moved), mask, source_mask, options)
        reached = run.transform @ start_tf @ total
        if refining:  # (fits exists whenever a refined round runs)
            reached = fits.keep_no_worse(total, reached)
        total = reached
        times["register"] += time.perf_counter() - tic
        rounds.append(total.copy())
    if refiner is not None and iterations > 1:  # the masks of the pose returned
        tic = time.perf_counter()
        mask, source_mask = refiner.predict_masks(template, transform_points(total, source))
        times["mask"] += time.perf_counter() - tic
    return Solution(total, mask, source_mask, run.info, rounds, run.correspondence_inliers)


def initial_transform(
    init: str,
    template: np.ndarray,
    source: np.ndarray,
    mask: np.ndarray | None,
    source_mask: np.ndarray | None = None,
) -> np.ndarray:
    """(B, 4, 4): the identity, or the shift of the centroid of the source points in use
    onto the centroid of the template points in use (``init="centroid"``)."""
    eye = np.broadcast_to(np.eye(4), (source.shape[0], 4, 4)).copy()
    if init == "identity":
        return eye
    eye[:, :3, 3] = _centroid(template, mask) - _centroid(source, usable(source_mask))
    return eye


def _centroid(points: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """(B, 3) centroid of the points (B, P, 3) in ``mask`` (B, P) bool, or of all."""
    if mask is None:
        return points.mean(1)
    weights = mask[..., None].astype(np.float64)
    return (points * weights).sum(1) / np.maximum(weights.sum(1), 1)


# Moved: the guard to the one fit module, the back-ends' helpers beside the back-ends.
__getattr__ = moved_names(
    __name__,
    {"RoundFits": "masknet.registration.judge.fit"}
    | {
        name: "masknet.registration.solvers.backends.base"
        for name in ("keep_source_points", "points_in_use", "check_template_points")
    },
)
