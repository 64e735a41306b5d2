"""``masknet.register``: registration (ICP) with or without MaskNet's inlier mask.

``register(template, source)`` runs *Mask-ICP*: MaskNet predicts which template
points the partial source sees, and only those take part in ICP. With
``use_mask=False`` it is plain ICP. ``iterations=n`` repeats {mask on the moved
source -> register -> move the source}, composing the transforms.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from masknet.errors import MaskNetError
from masknet.models.masknet import MaskNet, _as_batch
from masknet.registration.icp import ICPSolution, icp
from masknet.registration.open3d_icp import open3d_icp

__all__ = ["RegistrationResult", "register", "METHODS"]

METHODS = ("icp", "open3d-icp")
_OPTIONS = {
    "icp": ("max_iterations", "tolerance", "max_correspondence_distance"),
    "open3d-icp": (
        "max_iterations",
        "max_correspondence_distance",
        "relative_fitness",
        "relative_rmse",
    ),
}
_DEFAULT_MAX_ITERATIONS = 10


@dataclass
class RegistrationResult:
    """What :func:`register` returns. Arrays are numpy, float64 unless stated.

    The transform maps **source points into the template frame**,
    ``template ~= source @ R.T + t``; see :mod:`masknet.geometry.se3`. Shapes are
    given for one pair, with a leading batch dimension B for batched input.

    Attributes:
        R: (3, 3) or (B, 3, 3) rotation.
        t: (3,) or (B, 3) translation.
        transform: (4, 4) or (B, 4, 4), ``[[R, t], [0, 1]]``.
        mask: (N,) or (B, N) bool, the template points used in the last round;
            None without a mask.
        times: seconds per stage, summed over rounds: ``"mask"`` (MaskNet),
            ``"register"`` (the method) and ``"total"`` (the whole call).
        info: what the method reported in the last round, as numpy:
            ``converged`` (bool), ``fitness``, ``inlier_rmse`` (Open3D's definitions,
            measured against the template points used), ``iterations`` (int; -1 where
            the method does not report it), each () or (B,).
        rounds: the cumulative transform after each round, (4, 4) or (B, 4, 4) each;
            ``rounds[-1]`` equals ``transform``.
    """

    R: np.ndarray
    t: np.ndarray
    transform: np.ndarray
    mask: np.ndarray | None
    times: dict[str, float] = field(default_factory=dict)
    info: dict[str, np.ndarray] = field(default_factory=dict)
    rounds: list[np.ndarray] = field(default_factory=list)


@functools.lru_cache(maxsize=1)
def _default_model() -> MaskNet:
    """The shipped MaskNet weights, loaded once per process."""
    return MaskNet.pretrained()


def register(
    template: np.ndarray,
    source: np.ndarray,
    method: str = "icp",
    use_mask: bool = True,
    iterations: int = 1,
    model: MaskNet | None = None,
    k: int | None = None,
    threshold: float | None = None,
    **options: Any,
) -> RegistrationResult:
    """Register a partial source to a full template, optionally through MaskNet's mask.

    Args:
        template: (N, 3) or (B, N, 3) full template cloud(s).
        source: (M, 3) or (B, M, 3) partial source cloud(s), in original
            coordinates (MaskNet scales each pair internally).
        method: ``"icp"`` (batched torch ICP, :func:`masknet.registration.icp`) or
            ``"open3d-icp"`` (Open3D's point-to-point ICP, one pair at a time).
        use_mask: Mask-X (True) or plain X (False).
        iterations: rounds of {mask -> register -> move the source}.
        model: the MaskNet to use; None loads the shipped weights once
            (``MaskNet.pretrained()``).
        k, threshold: inlier selection, passed to :meth:`MaskNet.predict_mask`
            (default top-k with k = M); only with ``use_mask=True``.
        **options: passed to the method. ``"icp"``: ``max_iterations`` (default 10),
            ``tolerance``, ``max_correspondence_distance``. ``"open3d-icp"``:
            ``max_iterations`` (default 10), ``max_correspondence_distance``,
            ``relative_fitness``, ``relative_rmse``.

    Returns:
        RegistrationResult (source -> template, see :mod:`masknet.geometry.se3`).

    Raises:
        MaskNetError: bad clouds (shape, NaN/inf, fewer than 3 points, batch sizes),
            an unknown method or option, bad iterations/k/threshold, or (for
            ``"open3d-icp"``) no Open3D.
    """
    start = time.perf_counter()
    if method not in METHODS:
        raise MaskNetError(f"unknown registration method {method!r}; choose from {METHODS}")
    unknown = sorted(set(options) - set(_OPTIONS[method]))
    if unknown:
        raise MaskNetError(
            f"unknown option(s) for method {method!r}: {', '.join(unknown)} "
            f"(accepted: {', '.join(_OPTIONS[method])})"
        )
    if isinstance(iterations, bool) or not isinstance(iterations, int | np.integer):
        raise MaskNetError(f"iterations must be an integer >= 1, got {iterations!r}")
    if iterations < 1:
        raise MaskNetError(f"iterations must be >= 1, got {iterations}")
    if k is not None and threshold is not None:
        raise MaskNetError("give either k or threshold, not both")
    if k is not None and (isinstance(k, bool) or not isinstance(k, int | np.integer) or k < 1):
        raise MaskNetError(f"k must be an integer >= 1, got {k!r}")
    if not use_mask and (k is not None or threshold is not None):
        raise MaskNetError("k and threshold select MaskNet's inliers; they need use_mask=True")
    tpl, src, single = _as_numpy_batch(template, source)
    options.setdefault("max_iterations", _DEFAULT_MAX_ITERATIONS)
    if use_mask and model is None:
        model = _default_model()

    b = tpl.shape[0]
    total = np.broadcast_to(np.eye(4), (b, 4, 4)).copy()
    times = {"mask": 0.0, "register": 0.0}
    rounds: list[np.ndarray] = []
    mask: np.ndarray | None = None
    solution: ICPSolution | None = None
    for _ in range(iterations):
        moved = src @ total[:, :3, :3].transpose(0, 2, 1) + total[:, None, :3, 3]
        if use_mask:
            tic = time.perf_counter()
            mask = model.predict_mask(tpl, moved, k=k, threshold=threshold)
            times["mask"] += time.perf_counter() - tic
        tic = time.perf_counter()
        solution = _METHOD_RUNNERS[method](tpl, moved, mask, options)
        times["register"] += time.perf_counter() - tic
        total = solution.transform.double().numpy() @ total
        rounds.append(total[0].copy() if single else total.copy())

    def out(a: np.ndarray) -> np.ndarray:
        return a[0] if single else a

    info = {
        "converged": solution.converged.numpy(),
        "fitness": solution.fitness.double().numpy(),
        "inlier_rmse": solution.inlier_rmse.double().numpy(),
        "iterations": solution.iterations.numpy(),
    }
    times["total"] = time.perf_counter() - start
    return RegistrationResult(
        R=out(total[:, :3, :3].copy()),
        t=out(total[:, :3, 3].copy()),
        transform=out(total),
        mask=None if mask is None else out(mask),
        times=times,
        info={key: out(value) for key, value in info.items()},
        rounds=rounds,
    )


def _as_numpy_batch(template: Any, source: Any) -> tuple[np.ndarray, np.ndarray, bool]:
    """Validate as :meth:`MaskNet.predict` does; return float64 (B, N, 3), (B, M, 3), single."""
    t, s = np.asarray(template), np.asarray(source)
    for name, a in (("template", t), ("source", s)):
        if a.dtype.kind not in "iuf":
            raise MaskNetError(f"{name} must hold numbers, got an array of dtype {a.dtype}")
    _, _, single = _as_batch(t, s)
    t, s = t.astype(np.float64), s.astype(np.float64)
    return (t[None], s[None], True) if single else (t, s, False)


def _run_icp(
    template: np.ndarray, source: np.ndarray, mask: np.ndarray | None, options: dict
) -> ICPSolution:
    valid = None if mask is None else torch.from_numpy(mask)
    try:
        return icp(
            torch.from_numpy(source), torch.from_numpy(template), template_valid=valid, **options
        )
    except ValueError as exc:
        raise MaskNetError(f"icp: {exc}") from exc


def _run_open3d_icp(
    template: np.ndarray, source: np.ndarray, mask: np.ndarray | None, options: dict
) -> ICPSolution:
    parts = []
    for i in range(template.shape[0]):
        target = template[i] if mask is None else template[i][mask[i]]
        try:
            parts.append(open3d_icp(source[i], target, **options))
        except (ValueError, TypeError) as exc:
            raise MaskNetError(f"open3d-icp: {exc}") from exc
    return ICPSolution(*(torch.cat(field_parts) for field_parts in zip(*parts, strict=True)))


_METHOD_RUNNERS: dict[
    str, Callable[[np.ndarray, np.ndarray, np.ndarray | None, dict], ICPSolution]
] = {"icp": _run_icp, "open3d-icp": _run_open3d_icp}
