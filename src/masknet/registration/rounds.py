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

__all__ = ["RoundsResult", "apply_transform", "keep_source_points", "mask_and_register"]


class RoundsResult(NamedTuple):
    """transform: (B, 4, 4) source -> template after the last round. mask: (B, N) bool
    template points in use in the last round, or None. source_mask: (B, M) bool source
    points a two-sided MaskNet kept, or None. run: the last round's back-end run.
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
) -> RoundsResult:
    """``iterations`` rounds on template (B, N, 3) and source (B, M, 3), float64.

    ``model`` None is plain X. ``start`` (B, 4, 4) is the transform the first round
    starts from (identity by default). Seconds spent are added to ``times["mask"]``
    and ``times["register"]``.
    """
    b = template.shape[0]
    total = np.broadcast_to(np.eye(4), (b, 4, 4)).copy() if start is None else start.copy()
    rounds: list[np.ndarray] = []
    mask = source_mask = None
    run = None
    for _ in range(iterations):
        moved = apply_transform(total, source)
        if model is not None:
            tic = time.perf_counter()
            if isinstance(model, TwoSidedMaskNet):
                mask, source_mask = model.predict_masks(
                    template, moved, k=k, threshold=threshold, precision=precision
                )
                moved = keep_source_points(moved, source_mask)
            else:
                mask = model.predict_mask(
                    template, moved, k=k, threshold=threshold, precision=precision
                )
            times["mask"] += time.perf_counter() - tic
        tic = time.perf_counter()
        start_tf = initial_transform(init, moved, template, mask)
        run = BACKENDS[method](template, apply_transform(start_tf, moved), mask, options)
        times["register"] += time.perf_counter() - tic
        total = run.transform @ start_tf @ total
        rounds.append(total.copy())
    return RoundsResult(total, mask, source_mask, run, rounds)


def keep_source_points(source: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Sources (B, M, 3) whose rejected points (``keep`` (B, M) False) are replaced by
    kept ones, cycled in order, so a batch keeps one shape and every back-end sees only
    kept points. A pair with fewer than 3 kept points stays as it was."""
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
