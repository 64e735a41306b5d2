"""Denoising: remove the points of a scan that a clean template does not explain.

Given a clean template X of an object and a noisy cloud Y of the same object (a scan with
outliers), :func:`denoise` decides for every point of Y whether X explains it: by its
distance to X (``method="distance"``, the default; the clouds must be aligned), or by
the two-sided MaskNet's source mask (``method="masknet"``; the shipped
``masknet2_scans`` weights), which needs no alignment: it was trained on pairs
misaligned by up to 45 degrees. A paper MaskNet trained the other way round (``masknet
train --model denoise``) can be passed as ``model`` too.

Open3D's statistical and radius outlier removal are wrapped here too, as the
peers the benchmark compares against (they need no template).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np
from torch import Tensor

from masknet.errors import MaskNetError, checks_done, warn, warns_once
from masknet.geometry.clouds import as_cloud_batch, median_spacing, points_of, unit_radius
from masknet.geometry.knn import cloud_tree, knn_points
from masknet.geometry.open3d_clouds import to_open3d
from masknet.geometry.sampling import farthest_point_sample, spread_mask
from masknet.models.masknet import MaskNet
from masknet.models.refine import RefineMaskNet
from masknet.models.two_sided import TwoSidedMaskNet
from masknet.runtime import small_blas

__all__ = [
    "DenoiseResult",
    "denoise",
    "open3d_radius_outlier_removal",
    "open3d_statistical_outlier_removal",
]


class DenoiseResult(NamedTuple):
    """points: (K, 3) kept points of the noisy cloud, in its own units and order.
    mask: (P,) bool, True for kept points. scores: (P,) float32 in [0, 1]."""

    points: np.ndarray
    mask: np.ndarray
    scores: np.ndarray


# Clouds larger than this are scored on a farthest-point sample and the labels spread
# to every point from its nearest sampled one (the network saw 512-1024 points).
NETWORK_POINTS = 2048


@functools.lru_cache(maxsize=1)
def _default_model() -> TwoSidedMaskNet:
    return TwoSidedMaskNet.pretrained("scans")


@functools.lru_cache(maxsize=1)
def _default_refiner() -> RefineMaskNet:
    return RefineMaskNet.pretrained()


# "distance" and "refined" need aligned clouds; "masknet" does not.
METHODS = ("distance", "masknet", "refined")
ALIGNED = ("distance", "refined")

# Below this share of the template within 3 template spacings of the noisy cloud (and
# under half of the noisy cloud within as much of the template), the clouds are taken to
# be unaligned. On 40 ModelNet40 pairs (70% views, with and without 10% outliers) the
# aligned clouds covered at least 74% of the template, and the pairs as made (up to 45
# degrees and a unit translation apart) a median of 2-6%.
ALIGNED_COVERAGE = 0.2


@small_blas
@warns_once
def denoise(
    template: np.ndarray,
    noisy: np.ndarray,
    *,
    method: str = "distance",
    model: TwoSidedMaskNet | MaskNet | None = None,
    threshold: float = 0.5,
    max_distance: float | None = None,
    precision: str = "auto",
) -> DenoiseResult:
    """Remove the points of ``noisy`` (P, 3) that the clean ``template`` (N, 3) does not explain.

    The clouds come in the project's order, template first; every option is keyword-only.

    For ``"distance"`` and ``"refined"`` the clouds must be aligned (denoise after a
    registration, e.g. ``register`` and then this on the moved source); ``"masknet"``
    with the two-sided network does not need it.

    Example::

        kept = denoise(model_cloud, scan, method="masknet").points

    Args:
        method: ``"distance"`` (the default: keep points within ``max_distance`` of their
            nearest template point; default three times the template's point spacing) or
            ``"masknet"`` (the network scores each noisy point given the template; both
            are scaled by the template's radius, so the outliers cannot set the scale), or
            ``"refined"`` (the refinement mask of the iterative loop,
            :class:`~masknet.models.refine.RefineMaskNet`, which sees the two clouds in
            one frame: for registered clouds). Noisy clouds over 2,048 points are scored on a farthest-point sample of
            2,048 and each point takes the label of its nearest sampled point.
        model: for ``"masknet"``: a :class:`TwoSidedMaskNet` (None: the shipped
            ``masknet2_scans`` weights) or a paper MaskNet trained for denoising
            (``masknet train --model denoise``; aligned clouds only); for ``"refined"``:
            a :class:`RefineMaskNet` (None: the shipped ``refinemask_scans``).
        threshold: for ``"masknet"`` and ``"refined"``: keep points scoring at least this.
        max_distance: for ``"distance"``, in the clouds' units.
        precision: MaskNet's inference precision (``"auto"``: bf16 where native).

    Returns:
        DenoiseResult; ``scores`` are the network's for ``"masknet"`` and ``"refined"``, and
        ``exp(-(d / max_distance)^2)`` of the distance d for ``"distance"``.
    """
    if method not in METHODS:
        raise MaskNetError(f"unknown denoising method {method!r}; choose {', '.join(METHODS)}")
    if not 0 <= threshold <= 1:
        raise MaskNetError(f"threshold must be in [0, 1], got {threshold}")
    template, noisy = points_of(template), points_of(noisy)  # Open3D clouds: their points
    x, y = _checked_pair(template, noisy)
    near = 3 * median_spacing(template)  # the default rule's distance
    if method in ALIGNED:  # each noisy point's distance to the template: the rule's, and the
        # alignment warning's
        d = knn_points(y.double(), x.double(), 1).dists[0, :, 0].sqrt().numpy()
        _warn_if_apart(template, noisy, d, near, method)
    if method == "distance":
        limit = near if max_distance is None else max_distance
        if not limit > 0:
            raise MaskNetError(f"max_distance must be positive, got {limit}")
        mask = d <= limit
        scores = np.exp(-((d / limit) ** 2)).astype(np.float32)
        return DenoiseResult(np.asarray(noisy)[mask], mask, scores)
    if model is None:
        model = _default_refiner() if method == "refined" else _default_model()
    y_np = y[0].numpy()
    sampled = None
    if len(y_np) > NETWORK_POINTS:
        sampled = farthest_point_sample(y_np, NETWORK_POINTS).indices
        y = y[:, sampled]
    if method == "refined" and x.shape[1] > NETWORK_POINTS:
        # the network compares the two clouds' spacings: sample both alike
        x = x[:, farthest_point_sample(x[0].numpy(), NETWORK_POINTS).indices]
    # The networks check the clouds again under their own argument names; they were
    # checked above as "template" and "noisy", so the repeats stay quiet.
    with checks_done():
        if isinstance(model, TwoSidedMaskNet | RefineMaskNet):
            # predict's normalize scales both clouds by the template's radius.
            scores = model.predict(x.numpy(), y.numpy(), precision=precision)[1][0]
        else:  # a paper MaskNet trained for denoising scores its first cloud: the noisy one
            radius = unit_radius(x)[:, None, None]
            scores = model.predict(
                (y / radius).numpy(), (x / radius).numpy(), precision=precision, normalize=False
            )[0]
    if sampled is not None:
        scores = spread_mask(y_np, sampled, scores)
    mask = scores >= threshold
    return DenoiseResult(np.asarray(noisy)[mask], mask, scores)


def _warn_if_apart(
    template: np.ndarray, noisy: np.ndarray, to_template: np.ndarray, limit: float, method: str
) -> None:
    """Warn where the clouds look unaligned: under half of ``noisy`` (P, 3) lies within
    ``limit`` of ``template`` (N, 3) (``to_template``: (P,) each noisy point's distance to
    it) and under ALIGNED_COVERAGE of the template within ``limit`` of it. A method that
    needs aligned clouds would then remove nearly all; a scan that is mostly clutter around
    the object still covers the object. Aligned clouds cost no more than the distances."""
    if np.mean(to_template <= limit) >= 0.5:
        return
    tree = cloud_tree(np.asarray(noisy, np.float64))
    covered = float(np.mean(tree.query(np.asarray(template, np.float64))[0] <= limit))
    if covered < ALIGNED_COVERAGE:
        warn(
            f"only {covered:.0%} of the template lies within {limit:.3g} of the noisy cloud: "
            f"method {method!r} needs the clouds aligned (register them first and denoise "
            "the moved scan, or use method 'masknet')"
        )


def _checked_pair(template: np.ndarray, noisy: np.ndarray) -> tuple[Tensor, Tensor]:
    """One template (N, 3) and one noisy cloud (P, 3), checked under their own names:
    float32 tensors (1, N, 3) and (1, P, 3)."""
    if np.ndim(template) != 2 or np.ndim(noisy) != 2:
        raise MaskNetError(
            "denoise takes one template (N, 3) and one noisy cloud (P, 3); "
            f"got shapes {np.shape(template)} and {np.shape(noisy)}"
        )
    x, y, _ = as_cloud_batch(template, noisy, names=("template", "noisy"))
    return x, y


def _kept_mask(count: int, kept_index: list[int]) -> np.ndarray:
    mask = np.zeros(count, dtype=bool)
    mask[np.asarray(kept_index, dtype=np.int64)] = True
    return mask


def open3d_statistical_outlier_removal(
    points: np.ndarray, nb_neighbors: int = 20, std_ratio: float = 2.0
) -> np.ndarray:
    """Open3D's ``remove_statistical_outlier``: (P, 3) -> kept mask (P,) bool."""
    _, kept = to_open3d(points, feature="Open3D outlier removal").remove_statistical_outlier(
        nb_neighbors, std_ratio
    )
    return _kept_mask(len(points), kept)


def open3d_radius_outlier_removal(
    points: np.ndarray, nb_points: int = 8, radius: float = 0.1
) -> np.ndarray:
    """Open3D's ``remove_radius_outlier``: (P, 3) -> kept mask (P,) bool.

    ``radius`` is in the cloud's units (0.1 suits unit-radius ModelNet40 shapes).
    """
    _, kept = to_open3d(points, feature="Open3D outlier removal").remove_radius_outlier(
        nb_points, radius
    )
    return _kept_mask(len(points), kept)
