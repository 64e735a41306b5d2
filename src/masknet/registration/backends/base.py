"""What every back-end adapter returns."""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

__all__ = ["Backend", "BackendRun"]


class BackendRun(NamedTuple):
    """One run of a method on a batch of pairs."""

    transform: np.ndarray  # (B, 4, 4) float64, source -> template
    info: dict[str, np.ndarray]  # (B,) each
    correspondence_inliers: np.ndarray | None = None  # (B, N) bool


# An adapter: (template (B, N, 3), source (B, M, 3), mask (B, N) bool or None, options)
# -> BackendRun, all numpy float64. The mask selects the template points in use.
Backend = Callable[[np.ndarray, np.ndarray, "np.ndarray | None", dict], BackendRun]
