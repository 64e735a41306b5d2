"""``evaluate_registration``: how well a transform puts the source on the template.

The same measure as Open3D's ``pipelines.registration.evaluate_registration``: a source
point is an inlier when its nearest template point, after the transform, is within
``max_distance``; ``fitness`` is the fraction of source points that are inliers and
``inlier_rmse`` the root mean square of their distances. Unlike the ``fitness`` an ICP
run reports (which counts every pair when it has no distance cut-off), it judges any
method's result on the same footing, and says when a registration has failed.

Every argument is given by name. Open3D's function of the same name takes ``(source,
target, max_correspondence_distance, transformation)``: a call in that order would run and
measure the wrong cloud, so a positional call is a ``TypeError`` instead.

Example::

    result = register(template, source)
    quality = evaluate_registration(template=template, source=source, transform=result.transform)
    if quality.fitness < 0.3:
        print("the source barely touches the template: check the result")
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch

from masknet.errors import MaskNetError
from masknet.geometry.clouds import median_spacing
from masknet.geometry.knn import knn_points
from masknet.geometry.se3 import transform_points
from masknet.registration.validation import as_numpy_batch, as_rigid_transforms

__all__ = ["DEFAULT_SPACINGS", "RegistrationQuality", "evaluate_registration"]

# The default inlier distance, in template spacings (median nearest-neighbour distance):
# where right and wrong results fit most differently (docs/RESULTS.md, "Did a registration
# work?", scripts/fit_calibration.py); at 3 spacings wrong results fit as well as right ones.
DEFAULT_SPACINGS = 1.5


class RegistrationQuality(NamedTuple):
    """fitness: () or (B,), the fraction of source points within ``max_distance`` of
    the template. inlier_rmse: () or (B,), the root mean square distance of those points,
    in input units (0 where there are none, as Open3D). max_distance: () or (B,), the
    distance used."""

    fitness: np.ndarray
    inlier_rmse: np.ndarray
    max_distance: np.ndarray


def evaluate_registration(
    *,
    template: np.ndarray,
    source: np.ndarray,
    transform: np.ndarray,
    max_distance: float | None = None,
) -> RegistrationQuality:
    """Inlier fraction and RMSE of ``source`` moved by ``transform`` against ``template``.

    Keyword arguments only (``evaluate_registration(template=t, source=s, transform=T)``):
    Open3D's ``evaluate_registration`` takes the source first, and a call in its order
    would measure the wrong cloud.

    Args:
        template: (N, 3) or (B, N, 3) points.
        source: (M, 3) or (B, M, 3) points.
        transform: (4, 4) or (B, 4, 4) source -> template, as ``register`` returns it.
        max_distance: inlier cut-off in input units; None takes ``DEFAULT_SPACINGS``
            times each template's median nearest-neighbour distance, so the result
            does not depend on the unit.

    Returns:
        RegistrationQuality, unbatched for unbatched clouds.

    Raises:
        MaskNetError: bad clouds (shape, NaN/inf, too few points) or a bad transform
            or ``max_distance``.
    """
    template_b, source_b, single = as_numpy_batch(template, source)
    tf = as_rigid_transforms(transform, template_b.shape[0])
    if max_distance is not None and (
        isinstance(max_distance, bool)
        or not isinstance(max_distance, int | float | np.number)
        or not (np.isfinite(max_distance) and max_distance > 0)
    ):
        raise MaskNetError(f"max_distance must be a positive number, got {max_distance!r}")
    if max_distance is None:
        limits = np.array([DEFAULT_SPACINGS * median_spacing(t) for t in template_b])
    else:
        limits = np.full(len(template_b), float(max_distance))
    moved = transform_points(torch.from_numpy(tf), torch.from_numpy(source_b))
    d2 = knn_points(moved, torch.from_numpy(template_b), 1).dists[..., 0].numpy()
    inlier = d2 <= limits[:, None] ** 2
    count = inlier.sum(1)
    fitness = count / d2.shape[1]
    rmse = np.sqrt(np.where(inlier, d2, 0.0).sum(1) / np.maximum(count, 1))

    def out(a: np.ndarray) -> np.ndarray:
        return a[0] if single else a

    return RegistrationQuality(out(fitness), out(rmse), out(limits))
