"""``evaluate_registration``: how well a transform puts the source on the template.

The same measure as Open3D's ``pipelines.registration.evaluate_registration``: a source
point is an inlier when its nearest template point, after the transform, is within
``max_correspondence_distance``; ``fitness`` is the fraction of source points that are inliers and
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

import warnings

import numpy as np

from masknet.errors import MaskNetError
from masknet.geometry.se3 import transform_points
from masknet.registration.fit import RegistrationQuality, inlier_fit
from masknet.registration.options import DEFAULT_SPACINGS
from masknet.registration.validation import as_numpy_batch, as_rigid_transforms

__all__ = ["DEFAULT_SPACINGS", "RegistrationQuality", "evaluate_registration", "inlier_fit"]


def given_cut(
    max_correspondence_distance: float | None, max_distance: float | None, function: str
) -> float | None:
    """The cut-off a caller gave, checked: ``max_correspondence_distance``, or the
    deprecated ``max_distance`` with a DeprecationWarning (not both); None if neither."""
    if max_distance is not None:
        if max_correspondence_distance is not None:
            raise MaskNetError(f"{function}: give max_correspondence_distance only")
        warnings.warn(
            f"{function}(max_distance=...) is deprecated; use max_correspondence_distance=, "
            "Open3D's name",
            DeprecationWarning,
            stacklevel=3,
        )
        max_correspondence_distance = max_distance
    cut = max_correspondence_distance
    if cut is not None and (
        isinstance(cut, bool | np.bool_)
        or not isinstance(cut, int | float | np.number)
        or not (np.isfinite(cut) and cut > 0)
    ):
        raise MaskNetError(f"max_correspondence_distance must be a positive number, got {cut!r}")
    return None if cut is None else float(cut)


def evaluate_registration(
    *,
    template: np.ndarray,
    source: np.ndarray,
    transform: np.ndarray,
    max_correspondence_distance: float | None = None,
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
        max_correspondence_distance: inlier cut-off in input units (Open3D's name); None
            takes ``DEFAULT_SPACINGS`` times each template's median nearest-neighbour
            distance (over a seeded subset of 4,096 points for larger templates), so the
            result does not depend on the unit.
        max_distance: the former name of ``max_correspondence_distance``, deprecated.

    Returns:
        RegistrationQuality, unbatched for unbatched clouds.

    Raises:
        MaskNetError: bad clouds (shape, NaN/inf, too few points) or a bad transform
            or cut-off.
    """
    cut = given_cut(max_correspondence_distance, max_distance, "evaluate_registration")
    template_b, source_b, single = as_numpy_batch(template, source)
    tf = as_rigid_transforms(transform, template_b.shape[0])
    quality = inlier_fit(template_b, transform_points(tf, source_b), cut)
    if single:
        return RegistrationQuality(*(a[0] for a in quality))
    return quality
