"""What every adapter of the method table takes and returns."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

__all__ = ["Backend", "BackendRun", "MaskModels", "Pipeline", "PipelineRun"]


class BackendRun(NamedTuple):
    """One run of a method on a batch of pairs."""

    transform: np.ndarray  # (B, 4, 4) float64, source -> template
    info: dict[str, np.ndarray]  # (B,) each
    correspondence_inliers: np.ndarray | None = None  # (B, N) bool


class PipelineRun(NamedTuple):
    """A whole pipeline's answer (``auto``, ``robust``) for a batch of pairs, one by one.

    transform: (B, 4, 4) source -> template. mask: (B, N) bool template points on the
    overlap, or None without a network. source_mask: (B, M) bool source points kept, or
    None. info: (B,) or (B, 4, 4) arrays (``path``, ``fitness``, ``runner_up``, ...)."""

    transform: np.ndarray
    mask: np.ndarray | None
    source_mask: np.ndarray | None
    info: dict[str, np.ndarray]


# A back-end adapter: one round of a method on a batch, all numpy float64.
#   (template (B, N, 3), source (B, M, 3), template_mask (B, N) bool | None,
#    source_mask (B, M) bool | None, options: the method's typed options) -> BackendRun
# The masks select the points in use; a source point outside source_mask takes no part.
Backend = Callable[
    [np.ndarray, np.ndarray, "np.ndarray | None", "np.ndarray | None", Any], BackendRun
]

# A pipeline adapter: a whole call at full resolution, pair by pair.
#   (template (B, N, 3), source (B, M, 3), template_net (B, n, 3), source_net (B, m, 3):
#    the clouds sampled to the networks' size, models: MaskModels, options, times: seconds
#    per stage (added to), precision: the networks') -> PipelineRun
Pipeline = Callable[..., PipelineRun]


class MaskModels(NamedTuple):
    """The networks a pipeline masks with: ``first`` (its first look at the pair; None:
    no mask) and ``search`` (the escalation's two-sided network; None: no mask)."""

    first: Any
    search: Any
