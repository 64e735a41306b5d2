"""What every adapter of the method table takes and returns."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any, NamedTuple

import numpy as np

from masknet.errors import MaskNetError
from masknet.geometry.clouds import MIN_POINTS
from masknet.registration.terms.result import Solution

__all__ = [
    "Backend",
    "BackendRun",
    "MaskModels",
    "Pipeline",
    "check_template_points",
    "keep_source_points",
    "points_in_use",
    "usable",
]


class BackendRun(NamedTuple):
    """One run of a method on a batch of pairs."""

    transform: np.ndarray  # (B, 4, 4) float64, source -> template
    info: dict[str, np.ndarray]  # (B,) each
    correspondence_inliers: np.ndarray | None = None  # (B, N) bool


# A back-end adapter: one round of a method on a batch, all numpy float64.
#   (template (B, N, 3), source (B, M, 3), template_mask (B, N) bool | None,
#    source_mask (B, M) bool | None, options: the method's typed options) -> BackendRun
# The masks select the points in use; a source point outside source_mask takes no part.
Backend = Callable[
    [np.ndarray, np.ndarray, "np.ndarray | None", "np.ndarray | None", Any], BackendRun
]

# A pipeline adapter: a whole call at full resolution, pair by pair.
#   (template (B, N, 3), source (B, M, 3), nets: geometry.sampling.NetworkClouds, the
#    clouds sampled to the networks' size on first use, models: MaskModels, options,
#    times: seconds per stage (added to), precision: the networks') -> Solution
Pipeline = Callable[..., Solution]


class MaskModels(NamedTuple):
    """The networks a pipeline masks with: ``first`` (its first look at the pair; None:
    no mask) and ``search`` (the escalation's two-sided network; None: no mask)."""

    first: Any
    search: Any


# What the adapters share: which points of a pair are in use.


def keep_source_points(source: np.ndarray, keep: np.ndarray | None) -> np.ndarray:
    """One pair's kept source points: source (1, M, 3) and ``keep`` (1, M) bool ->
    (1, M', 3), each kept point once; unchanged where nothing is rejected or fewer than 3
    points are kept. A batch keeps one shape, so its back-ends take the mask instead (ICP's
    ``source_valid``) or run pair by pair (the networks)."""
    if keep is None or source.shape[0] != 1:
        return source
    kept = np.flatnonzero(keep[0])
    return source[:, kept] if MIN_POINTS <= len(kept) < source.shape[1] else source


def check_template_points(
    fewest: int,
    k: int | None = None,
    threshold: float | None = None,
    rule: str | None = None,
) -> None:
    """MaskNetError where a mask keeps fewer than 3 template points of a pair (``fewest``,
    the smallest count of a batch): nothing can be registered onto them.

    The advice fits what chose the mask: ``threshold`` or ``k`` as the caller gave them
    (neither: top-k with k = the source's points), or ``rule``, a mask that no option of
    the caller's set (the refiner's, one passed in), said as it is."""
    if fewest >= MIN_POINTS:
        return
    if rule is not None:
        how = rule
    elif threshold is not None:
        how = f"mask_threshold {threshold:g}; lower it, or give k instead"
    elif k is not None:
        how = f"top-k with k={k}; give k of at least {MIN_POINTS}"
    else:
        how = f"top-k with k = the source's points; the source needs at least {MIN_POINTS}"
    raise MaskNetError(
        f"the mask kept {fewest} template point(s); registration needs at least "
        f"{MIN_POINTS} ({how})"
    )


def points_in_use(
    template: np.ndarray,
    source: np.ndarray,
    mask: np.ndarray | None,
    source_mask: np.ndarray | None,
) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Pair by pair, the template points in use (N', 3) and the kept source points
    (M', 3) of template (B, N, 3) and source (B, M, 3): for back-ends that take one pair
    at a time."""
    keep = usable(source_mask)
    for i in range(template.shape[0]):
        target = template[i] if mask is None else template[i][mask[i]]
        yield target, source[i] if keep is None else source[i][keep[i]]


def usable(keep: np.ndarray | None) -> np.ndarray | None:
    """``keep`` (B, M) bool with pairs that keep under 3 points set to keep all (nothing
    sensible to register), or None."""
    if keep is None:
        return None
    return np.where((keep.sum(1) >= MIN_POINTS)[:, None], keep, True)
