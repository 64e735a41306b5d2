"""Checks of :func:`masknet.register`'s arguments, raising :class:`MaskNetError`."""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from masknet.errors import MaskNetError
from masknet.geometry.clouds import MIN_POINTS, check_pair
from masknet.io_checks import check_cloud, over_rows
from masknet.registration.terms.methods import INITS, METHODS

__all__ = [
    "as_numpy_batch",
    "as_rigid_transforms",
    "check_arguments",
    "finite_rows",
    "mask_threshold_of",
    "spread_rows",
]


def check_arguments(
    method: str,
    iterations: Any,
    k: Any,
    threshold: Any,
    use_mask: bool,
    init: str,
    refine_iterations: Any,
    max_points: Any,
) -> None:
    """Raise :class:`MaskNetError` for an unknown method or init, or bad iterations,
    refine_iterations, max_points, k or threshold (a method's own options check
    themselves: :mod:`masknet.registration.terms.options`)."""
    if method not in METHODS:
        raise MaskNetError(f"unknown registration method {method!r}; choose from {METHODS}")
    for name, value, low in (
        ("iterations", iterations, 1),
        ("refine_iterations", refine_iterations, 0),
        ("max_points", max_points, MIN_POINTS),
    ):
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < low:
            raise MaskNetError(f"{name} must be an integer >= {low}, got {value!r}")
    split_init(init)
    if k is not None and threshold is not None:
        raise MaskNetError("give either k or mask_threshold, not both")
    if k is not None and (isinstance(k, bool) or not isinstance(k, int | np.integer) or k < 1):
        raise MaskNetError(f"k must be an integer >= 1, got {k!r}")
    if not use_mask and (k is not None or threshold is not None):
        raise MaskNetError("k and mask_threshold select MaskNet's inliers; they need use_mask=True")


def mask_threshold_of(mask_threshold: float | None, threshold: float | None) -> float | None:
    """The mask's score cut-off a caller gave: ``mask_threshold``, or the deprecated
    ``threshold`` with a DeprecationWarning (not both). Renamed because Open3D's
    ``threshold`` is the pair cut-off, masknet's ``max_correspondence_distance``."""
    if threshold is None:
        return mask_threshold
    if mask_threshold is not None:
        raise MaskNetError("give mask_threshold only (threshold is its deprecated name)")
    warnings.warn(
        "register(threshold=...) is deprecated; it is mask_threshold=, MaskNet's score "
        "cut-off (Open3D's threshold, the pair cut-off, is max_correspondence_distance=)",
        DeprecationWarning,
        stacklevel=5,  # the caller of register, past its two decorators
    )
    return threshold


def split_init(init: Any) -> tuple[str, np.ndarray | None]:
    """``init`` as a named start and a starting pose: a name of :data:`INITS` gives
    (name, None), None the default (``"centroid"``); a (4, 4) or (B, 4, 4) array, Open3D's
    ``init``, gives ("identity", the array as float64), the source then moved by it before
    the method runs (the identity matrix is the same start as ``"identity"``)."""
    if init is None:
        return "centroid", None
    if isinstance(init, str):
        if init not in INITS:
            raise MaskNetError(f"unknown init {init!r}; choose from {INITS} or a (4, 4) matrix")
        return init, None
    try:
        matrix = np.array(init, dtype=np.float64)
    except (TypeError, ValueError):
        raise MaskNetError(
            f"init must be one of {INITS} or a (4, 4) or (B, 4, 4) transform of numbers"
        ) from None
    if matrix.shape[-2:] != (4, 4) or matrix.ndim not in (2, 3):
        raise MaskNetError(
            f"init must be one of {INITS} or a (4, 4) or (B, 4, 4) transform, got shape "
            f"{matrix.shape}"
        )
    return "identity", matrix


def as_numpy_batch(template: Any, source: Any) -> tuple[np.ndarray, np.ndarray, bool]:
    """Validate as :meth:`MaskNet.predict` does; return float64 (B, N, 3), (B, M, 3), single."""
    t, s, single = check_pair(template, source)
    return t.astype(np.float64), s.astype(np.float64), single


def as_rigid_transforms(transform: np.ndarray, b: int) -> np.ndarray:
    """``transform`` (4, 4) or (B, 4, 4) as a writable float64 (B, 4, 4); refuses
    anything but finite rigid transforms."""
    tf = np.array(transform, dtype=np.float64)
    if tf.shape == (4, 4):
        tf = np.broadcast_to(tf, (b, 4, 4)).copy()  # writable, for torch
    if tf.shape != (b, 4, 4):
        raise MaskNetError(f"transform must be (4, 4) or ({b}, 4, 4), got {np.shape(transform)}")
    if not np.isfinite(tf).all():
        raise MaskNetError("transform holds NaN or inf: no pose to judge")
    rot = tf[:, :3, :3]
    rigid = np.allclose(rot @ rot.transpose(0, 2, 1), np.eye(3), atol=1e-4)
    if not rigid or (np.linalg.det(rot) < 0).any() or not np.allclose(tf[:, 3], [0, 0, 0, 1]):
        raise MaskNetError(
            "transform must be rigid: a rotation and a translation, last row 0 0 0 1"
        )
    return tf


def finite_rows(template: Any, source: Any) -> tuple:
    """The finite rows of one pair: template, source, and which rows they are (bool)."""
    if np.ndim(template) != 2 or np.ndim(source) != 2:
        raise MaskNetError("drop_nonfinite takes one pair: (N, 3) and (M, 3) clouds")
    template, template_rows = check_cloud(template, "template", drop_nonfinite=True)
    source, source_rows = check_cloud(source, "source", drop_nonfinite=True)
    return template, source, template_rows, source_rows


def spread_rows(mask: np.ndarray | None, rows: np.ndarray) -> np.ndarray | None:
    """A (1, kept) mask over all the input's rows (1, P), False where a row was dropped."""
    if mask is None:
        return None
    return over_rows(mask[0], rows)[None]
