"""The rounds of Mask-X: {mask -> initialise -> register -> move the source}, batched.

:func:`masknet.register` runs them once per call; the ``robust`` method runs them on
many rotation hypotheses at once (:mod:`masknet.registration.robust`).
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np
import torch

from masknet.geometry.align import centroid_alignment
from masknet.geometry.se3 import transform_points
from masknet.models.masknet import MaskNet
from masknet.models.two_sided import TwoSidedMaskNet
from masknet.registration.backends import BACKENDS, BackendRun
from masknet.registration.refinement import Refiner

__all__ = ["RoundsResult", "apply_transform", "keep_source_points", "mask_and_register"]


class RoundsResult(NamedTuple):
    """transform: (B, 4, 4) source -> template after the last round. mask: (B, N) bool
    template points in use in the last round (with a refiner and >= 2 rounds: its mask at
    the returned pose), or None. source_mask: (B, M) bool source points kept likewise (a
    two-sided MaskNet's or the refiner's), or None. run: the last round's back-end run.
    rounds: (B, 4, 4) transform after each round."""

    transform: np.ndarray
    mask: np.ndarray | None
    source_mask: np.ndarray | None
    run: BackendRun
    rounds: list[np.ndarray]


def mask_and_register(
    template: np.ndarray,
    source: np.ndarray,
    method: str,
    model: MaskNet | TwoSidedMaskNet | None,
    iterations: int,
    options: dict,
    times: dict[str, float],
    k: int | None = None,
    threshold: float | None = None,
    precision: str = "auto",
    init: str = "centroid",
    start: np.ndarray | None = None,
    refiner: Refiner | None = None,
) -> RoundsResult:
    """``iterations`` rounds on template (B, N, 3) and source (B, M, 3), float64.

    ``model`` None is plain X. ``start`` (B, 4, 4) is the transform the first round
    starts from (identity by default). ``refiner`` (see
    :mod:`masknet.registration.refinement`) masks both clouds in rounds >= 2, on the pair
    as the previous round left it, and those rounds start from that pose (no centroid
    shift); after the last round it masks the pair once more, at the pose reached. None
    runs ``model`` in every round (the paper's loop, each round starting with ``init``).
    Without a model (plain X), rounds >= 2 start from the pose reached. Seconds spent are
    added to ``times["mask"]`` and ``times["register"]``.
    """
    b = template.shape[0]
    total = np.broadcast_to(np.eye(4), (b, 4, 4)).copy() if start is None else start.copy()
    rounds: list[np.ndarray] = []
    mask = source_mask = None
    run = None
    for round_index in range(iterations):
        moved = apply_transform(total, source)
        refining = refiner is not None and round_index > 0
        if refining:
            tic = time.perf_counter()
            mask, source_mask = refiner.predict_masks(template, moved)
            times["mask"] += time.perf_counter() - tic
        elif model is not None:
            tic = time.perf_counter()
            if isinstance(model, TwoSidedMaskNet):
                mask, source_mask = model.predict_masks(
                    template, moved, k=k, threshold=threshold, precision=precision
                )
            else:
                mask = model.predict_mask(
                    template, moved, k=k, threshold=threshold, precision=precision
                )
            times["mask"] += time.perf_counter() - tic
        if source_mask is not None:  # the back-end sees the kept source points only
            moved = keep_source_points(moved, source_mask)
        tic = time.perf_counter()
        # Later rounds start where the last one ended; only the paper's loop (the
        # network again in every round) re-centres, as it always did.
        restart = round_index > 0 and (refiner is not None or model is None)
        start_tf = initial_transform("identity" if restart else init, moved, template, mask)
        run = BACKENDS[method](template, apply_transform(start_tf, moved), mask, options)
        times["register"] += time.perf_counter() - tic
        total = run.transform @ start_tf @ total
        rounds.append(total.copy())
    if refiner is not None and iterations > 1:  # the masks of the pose returned
        tic = time.perf_counter()
        mask, source_mask = refiner.predict_masks(template, apply_transform(total, source))
        times["mask"] += time.perf_counter() - tic
    return RoundsResult(total, mask, source_mask, run, rounds)


def keep_source_points(source: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """The kept source points (``keep`` (B, M) bool) of sources (B, M, 3).

    One pair (B = 1): exactly its kept points, (1, M', 3). A batch keeps one shape, so
    rejected points are replaced by kept ones, cycled in order (a kept point may then
    count twice). A pair with fewer than 3 kept points stays as it was."""
    if source.shape[0] == 1:
        kept = np.flatnonzero(keep[0])
        return source[:, kept] if 3 <= len(kept) < source.shape[1] else source
    out = source.copy()
    for b in range(source.shape[0]):
        kept = np.flatnonzero(keep[b])
        if len(kept) >= 3 and len(kept) < source.shape[1]:
            out[b] = source[b, np.resize(kept, source.shape[1])]
    return out


def apply_transform(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(B, 4, 4) transforms applied to (B, P, 3) points (numpy wrapper of the SE(3) module)."""
    return transform_points(torch.from_numpy(transform), torch.from_numpy(points)).numpy()


def initial_transform(
    init: str, source: np.ndarray, template: np.ndarray, mask: np.ndarray | None
) -> np.ndarray:
    """(B, 4, 4): the identity, or the shift of the source centroid onto the centroid of
    the template points in use (``init="centroid"``)."""
    if init == "identity":
        return np.broadcast_to(np.eye(4), (source.shape[0], 4, 4)).copy()
    valid = None if mask is None else torch.from_numpy(mask)
    return centroid_alignment(
        template=torch.from_numpy(template), source=torch.from_numpy(source), template_valid=valid
    ).numpy()
