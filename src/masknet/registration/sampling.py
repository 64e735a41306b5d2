"""Large single pairs brought to the network's size (the mask goes back to every point by
:func:`masknet.geometry.sampling.spread_mask`)."""

from __future__ import annotations

import numpy as np

from masknet.errors import MaskNetError
from masknet.geometry.sampling import farthest_point_sample

__all__ = ["fit_to_network"]


def fit_to_network(
    template: np.ndarray, source: np.ndarray, single: bool, max_points: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Subsample a single large pair, template (1, N, 3) and source (1, M, 3), to at most
    ``max_points`` each; returns (template, source, template indices, source indices),
    the indices None where nothing was sampled."""
    n, m = template.shape[1], source.shape[1]
    if n <= max_points and m <= max_points:
        return template, source, None, None
    if not single:
        raise MaskNetError(
            f"batched clouds must have at most max_points={max_points} points "
            f"(got template {n}, source {m}); pass large clouds one pair at a time"
        )
    kept = farthest_point_sample(template[0], max_points)
    # The source at the template's spacing, so its size still reflects the overlap
    # (top-k selection uses it).
    src_idx = farthest_point_sample(source[0], max_points, min_spacing=kept.radius).indices
    return template[:, kept.indices], source[:, src_idx], kept.indices, src_idx
