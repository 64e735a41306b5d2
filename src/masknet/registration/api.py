"""``masknet.register``: one call for every registration method, with or without MaskNet.

``register(template, source, method=X)`` runs *Mask-X*: MaskNet predicts which
template points the partial source sees, and only those take part in X. With
``use_mask=False`` it is plain X, so X and Mask-X compare in one call.

One round is: (optionally) predict the mask for the source as it stands, move the
source by the initialisation (``init="centroid"``: its centroid onto the centroid
of the template points in use), run the method, compose. ``iterations=n`` repeats
rounds on the moved source (the paper's iterative scheme); ``refine_iterations``
ends with plain ICP against the whole template from the estimate reached.

Clouds larger than ``max_points`` (single pairs) are brought to the network's
size by farthest point sampling, the source at the template's spacing (see
:mod:`masknet.geometry.sampling`); the transform applies to the full clouds, and
the returned mask covers every template point (each takes the label of its
nearest sampled point).
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
import torch

from masknet.errors import MaskNetError
from masknet.geometry.align import centroid_alignment
from masknet.geometry.knn import knn_points
from masknet.geometry.sampling import farthest_point_sample
from masknet.geometry.se3 import transform_points
from masknet.models import REGISTRATION_NETWORKS
from masknet.models.masknet import MIN_POINTS, MaskNet, _as_batch, unit_radius
from masknet.registration.icp import icp
from masknet.registration.open3d_icp import open3d_icp

__all__ = ["RegistrationResult", "register", "METHODS", "METHOD_TITLES"]

NETWORK_METHODS = tuple(REGISTRATION_NETWORKS)  # pointnetlk, dcp, prnet, pcrnet, rpmnet
# Open3D's global registration on FPFH features: no iteration budget, no init.
GLOBAL_METHODS = ("open3d-ransac", "open3d-fgr")
METHODS = ("icp", "open3d-icp", *NETWORK_METHODS, *GLOBAL_METHODS)
# Each method's display name (X of "Mask-X").
METHOD_TITLES = {
    "icp": "ICP",
    "open3d-icp": "Open3D-ICP",
    "pointnetlk": "PointNetLK",
    "dcp": "DCP",
    "prnet": "PRNet",
    "pcrnet": "PCRNet",
    "rpmnet": "RPM-Net",
    "open3d-ransac": "Open3D-RANSAC",
    "open3d-fgr": "Open3D-FGR",
}
_OPTIONS = {
    "icp": ("max_iterations", "tolerance", "max_correspondence_distance"),
    "open3d-icp": (
        "max_iterations",
        "max_correspondence_distance",
        "relative_fitness",
        "relative_rmse",
    ),
    "pointnetlk": ("max_iterations", "tolerance", "network"),
    **{name: ("max_iterations", "network") for name in NETWORK_METHODS if name != "pointnetlk"},
    "open3d-ransac": ("max_iterations", "voxel_size", "confidence", "seed"),
    "open3d-fgr": ("max_iterations", "voxel_size"),
}
_DEFAULT_MAX_ITERATIONS = 10  # the paper's budget for ICP and PointNetLK
# Each learned network's own iteration count (its paper's): DCP 1, PRNet 3, PCRNet 8, ...
_DEFAULT_ITERATIONS = {
    **{m: _DEFAULT_MAX_ITERATIONS for m in METHODS},
    **{name: cls.default_iterations for name, cls in REGISTRATION_NETWORKS.items()},
}
INITS = ("centroid", "identity")


@dataclass
class RegistrationResult:
    """What :func:`register` returns. Arrays are numpy, float64 unless stated.

    The transform maps **source points into the template frame**,
    ``template ~= source @ R.T + t``; see :mod:`masknet.geometry.se3`. Shapes are
    given for one pair, with a leading batch dimension B for batched input.

    Attributes:
        R: (3, 3) or (B, 3, 3) rotation.
        t: (3,) or (B, 3) translation, in the input's units.
        transform: (4, 4) or (B, 4, 4), ``[[R, t], [0, 1]]``.
        mask: (N,) or (B, N) bool over the input template, the inliers used in the
            last round; None without a mask.
        times: seconds per stage, summed over rounds: ``"sample"`` (subsampling large
            clouds), ``"mask"`` (MaskNet), ``"register"`` (the method), ``"refine"``
            and ``"total"`` (the whole call).
        info: what the method reported in its last run, as numpy arrays, () or (B,)
            each. ICP methods: ``converged``, ``iterations`` (-1 where not reported),
            ``fitness`` and ``inlier_rmse`` (Open3D's definitions). PointNetLK:
            ``converged``, ``iterations``, ``feature_residual``.
        rounds: the cumulative transform after each round, (4, 4) or (B, 4, 4) each.
        sampled: (template, source) sizes the method ran on, for single pairs.
        correspondence_inliers: (N,) or (B, N) bool, for PRNet and RPM-Net: the template
            points taking part in a confident correspondence in the last round (the rule
            is in :mod:`masknet.models.prnet` and :mod:`masknet.models.rpmnet`); template
            points the network did not see (sampled away for its input size) are False;
            None for other methods.
    """

    R: np.ndarray
    t: np.ndarray
    transform: np.ndarray
    mask: np.ndarray | None
    times: dict[str, float] = field(default_factory=dict)
    info: dict[str, np.ndarray] = field(default_factory=dict)
    rounds: list[np.ndarray] = field(default_factory=list)
    sampled: tuple[int, int] | None = None
    correspondence_inliers: np.ndarray | None = None


class _Run(NamedTuple):
    transform: np.ndarray  # (B, 4, 4) float64, source -> template
    info: dict[str, np.ndarray]  # (B,) each
    correspondence_inliers: np.ndarray | None = None  # (B, N) bool


@functools.lru_cache(maxsize=1)
def _default_model() -> MaskNet:
    """The shipped MaskNet weights, loaded once per process."""
    return MaskNet.pretrained()


@functools.cache
def _default_network(method: str) -> torch.nn.Module:
    """The shipped weights of a learned registration network, loaded once per process."""
    return REGISTRATION_NETWORKS[method].pretrained().eval()


def register(
    template: np.ndarray,
    source: np.ndarray,
    method: str = "icp",
    use_mask: bool = True,
    iterations: int = 1,
    model: MaskNet | None = None,
    k: int | None = None,
    threshold: float | None = None,
    precision: str = "auto",
    init: str = "centroid",
    refine_iterations: int = 0,
    max_points: int = 1024,
    **options: Any,
) -> RegistrationResult:
    """Register a partial source to a full template, optionally through MaskNet's mask.

    Args:
        template: (N, 3) or (B, N, 3) full template cloud(s), any units.
        source: (M, 3) or (B, M, 3) partial source cloud(s), same units.
        method: ``"icp"`` (batched torch ICP), ``"open3d-icp"`` (Open3D's
            point-to-point ICP, pair by pair), a learned network: ``"pointnetlk"``,
            ``"dcp"``, ``"prnet"``, ``"pcrnet"`` or ``"rpmnet"`` (the shipped weights
            unless ``network=`` is given), ``"open3d-ransac"`` or ``"open3d-fgr"``
            (Open3D's global registration on FPFH features).
        use_mask: Mask-X (True) or plain X (False).
        iterations: rounds of {mask -> initialise -> register -> move the source}.
        model: the MaskNet to use; None loads the shipped weights once.
        k, threshold: inlier selection, as :meth:`MaskNet.predict_mask` (default
            top-k with k = M); only with ``use_mask=True``.
        precision: MaskNet's inference precision, as :meth:`MaskNet.predict`
            (``"auto"``: bf16 where the hardware runs it natively).
        init: ``"centroid"`` (default: translate the source centroid onto the
            centroid of the template points in use, i.e. the masked ones for Mask-X)
            or ``"identity"``. PointNetLK centres both clouds itself either way.
        refine_iterations: after the rounds, this many iterations of plain ICP
            against the whole template (0: none).
        max_points: single pairs larger than this are subsampled for the method
            (farthest point sampling); batches must already fit.
        **options: for the method. ``"icp"``: ``max_iterations`` (default 10),
            ``tolerance``, ``max_correspondence_distance``. ``"open3d-icp"``:
            ``max_iterations`` (default 10), ``max_correspondence_distance``,
            ``relative_fitness``, ``relative_rmse``. Learned networks: ``max_iterations``
            (default: the network's paper's, PointNetLK 10, DCP 1, PRNet 3, PCRNet 8,
            RPM-Net 5) and ``network`` (a model of :data:`~masknet.models.REGISTRATION_NETWORKS`);
            PointNetLK also ``tolerance``. ``"open3d-ransac"`` and ``"open3d-fgr"``
            (Open3D's global registration on FPFH features, pair by pair):
            ``voxel_size`` (feature scale as a fraction of the template's radius, default
            0.05); RANSAC also ``max_iterations`` (default 100,000), ``confidence``,
            ``seed``. They ignore ``init``.

    Returns:
        RegistrationResult (source -> template, see :mod:`masknet.geometry.se3`).

    Raises:
        MaskNetError: bad clouds (shape, NaN/inf, fewer than 3 points, batch sizes),
            an unknown method, option or init, bad iterations/k/threshold, or (for
            ``"open3d-icp"``) no Open3D.
    """
    start = time.perf_counter()
    _check_arguments(method, options, iterations, k, threshold, use_mask, init, refine_iterations)
    tpl_full, src_full, single = _as_numpy_batch(template, source)
    if method not in GLOBAL_METHODS:
        options.setdefault("max_iterations", _DEFAULT_ITERATIONS[method])
    if use_mask and model is None:
        model = _default_model()
    if method in NETWORK_METHODS and options.get("network") is None:
        options["network"] = _default_network(method)

    times = {"sample": 0.0, "mask": 0.0, "register": 0.0, "refine": 0.0}
    tic = time.perf_counter()
    tpl, src, template_index = _fit_to_network(tpl_full, src_full, single, max_points)
    times["sample"] = time.perf_counter() - tic

    b = tpl.shape[0]
    total = np.broadcast_to(np.eye(4), (b, 4, 4)).copy()
    rounds: list[np.ndarray] = []
    mask: np.ndarray | None = None
    run: _Run | None = None
    for _ in range(iterations):
        moved = _apply(total, src)
        if use_mask:
            tic = time.perf_counter()
            mask = model.predict_mask(tpl, moved, k=k, threshold=threshold, precision=precision)
            times["mask"] += time.perf_counter() - tic
        tic = time.perf_counter()
        start_tf = _initial_transform(init, moved, tpl, mask)
        run = _METHOD_RUNNERS[method](tpl, _apply(start_tf, moved), mask, options)
        times["register"] += time.perf_counter() - tic
        total = run.transform @ start_tf @ total
        rounds.append(total[0].copy() if single else total.copy())
    if refine_iterations:
        tic = time.perf_counter()
        refine_options = {"max_iterations": refine_iterations}
        total = _run_icp(tpl, _apply(total, src), None, refine_options).transform @ total
        times["refine"] = time.perf_counter() - tic

    inliers = run.correspondence_inliers
    if template_index is not None:
        if mask is not None:
            mask = _spread_mask(tpl_full[0], template_index, mask[0])[None]
        if inliers is not None:  # points the network never saw are not inliers
            full = np.zeros(tpl_full.shape[:2], bool)
            full[:, template_index] = inliers
            inliers = full

    def out(a: np.ndarray) -> np.ndarray:
        return a[0] if single else a

    times["total"] = time.perf_counter() - start
    return RegistrationResult(
        R=out(total[:, :3, :3].copy()),
        t=out(total[:, :3, 3].copy()),
        transform=out(total),
        mask=None if mask is None else out(mask),
        times=times,
        info={key: out(value) for key, value in run.info.items()},
        rounds=rounds,
        sampled=(tpl.shape[1], src.shape[1]) if single else None,
        correspondence_inliers=None if inliers is None else out(inliers),
    )


def _check_arguments(
    method: str,
    options: dict,
    iterations: Any,
    k: Any,
    threshold: Any,
    use_mask: bool,
    init: str,
    refine_iterations: Any,
) -> None:
    if method not in METHODS:
        raise MaskNetError(f"unknown registration method {method!r}; choose from {METHODS}")
    unknown = sorted(set(options) - set(_OPTIONS[method]))
    if unknown:
        raise MaskNetError(
            f"unknown option(s) for method {method!r}: {', '.join(unknown)} "
            f"(accepted: {', '.join(_OPTIONS[method])})"
        )
    for name, value, low in (
        ("iterations", iterations, 1),
        ("refine_iterations", refine_iterations, 0),
    ):
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < low:
            raise MaskNetError(f"{name} must be an integer >= {low}, got {value!r}")
    if init not in INITS:
        raise MaskNetError(f"unknown init {init!r}; choose from {INITS}")
    if k is not None and threshold is not None:
        raise MaskNetError("give either k or threshold, not both")
    if k is not None and (isinstance(k, bool) or not isinstance(k, int | np.integer) or k < 1):
        raise MaskNetError(f"k must be an integer >= 1, got {k!r}")
    if not use_mask and (k is not None or threshold is not None):
        raise MaskNetError("k and threshold select MaskNet's inliers; they need use_mask=True")


def _as_numpy_batch(template: Any, source: Any) -> tuple[np.ndarray, np.ndarray, bool]:
    """Validate as :meth:`MaskNet.predict` does; return float64 (B, N, 3), (B, M, 3), single."""
    t, s = np.asarray(template), np.asarray(source)
    for name, a in (("template", t), ("source", s)):
        if a.dtype.kind not in "iuf":
            raise MaskNetError(f"{name} must hold numbers, got an array of dtype {a.dtype}")
    _, _, single = _as_batch(t, s)
    t, s = t.astype(np.float64), s.astype(np.float64)
    return (t[None], s[None], True) if single else (t, s, False)


def _fit_to_network(
    template: np.ndarray, source: np.ndarray, single: bool, max_points: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Subsample a single large pair; returns (template, source, template indices or None)."""
    n, m = template.shape[1], source.shape[1]
    if n <= max_points and m <= max_points:
        return template, source, None
    if not single:
        raise MaskNetError(
            f"batched clouds must have at most max_points={max_points} points "
            f"(got template {n}, source {m}); pass large clouds one pair at a time"
        )
    kept = farthest_point_sample(template[0], max_points)
    # The source at the template's spacing, so its size still reflects the overlap
    # (top-k selection uses it).
    src_idx = farthest_point_sample(source[0], max_points, min_spacing=kept.radius).indices
    return template[:, kept.indices], source[:, src_idx], kept.indices


def _spread_mask(template: np.ndarray, sampled: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Give every template point (N, 3) the mask label of its nearest sampled point."""
    full = torch.from_numpy(template)[None]
    nearest = knn_points(full, full[:, sampled], 1).idx[0, :, 0].numpy()
    return mask[nearest]


def _apply(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(B, 4, 4) transforms applied to (B, P, 3) points (numpy wrapper of the SE(3) module)."""
    return transform_points(torch.from_numpy(transform), torch.from_numpy(points)).numpy()


def _initial_transform(
    init: str, source: np.ndarray, template: np.ndarray, mask: np.ndarray | None
) -> np.ndarray:
    if init == "identity":
        return np.broadcast_to(np.eye(4), (source.shape[0], 4, 4)).copy()
    valid = None if mask is None else torch.from_numpy(mask)
    return centroid_alignment(torch.from_numpy(source), torch.from_numpy(template), valid).numpy()


def _run_icp(
    template: np.ndarray, source: np.ndarray, mask: np.ndarray | None, options: dict
) -> _Run:
    """ICP in float32 about the template's centroid: about twice as fast as float64, and
    exact enough wherever the clouds sit (far from the origin float32 alone would not be)."""
    valid = None if mask is None else torch.from_numpy(mask)
    if mask is None:
        shift = template.mean(axis=1, keepdims=True)  # (B, 1, 3)
    else:  # the points in use only, so that masked-out points cannot change anything
        weights = mask[..., None].astype(np.float64)
        shift = (template * weights).sum(1, keepdims=True) / np.maximum(
            weights.sum(1, keepdims=True), 1
        )
    try:
        solution = icp(
            torch.from_numpy(source - shift).float(),
            torch.from_numpy(template - shift).float(),
            template_valid=valid,
            **options,
        )
    except ValueError as exc:
        raise MaskNetError(f"icp: {exc}") from exc
    centred = solution.transform.double().numpy()
    # T = Shift(c) @ T_centred @ Shift(-c): R unchanged, t = t_centred + c - R c.
    c = shift[:, 0]
    centred[:, :3, 3] += c - np.einsum("bij,bj->bi", centred[:, :3, :3], c)
    return _Run(centred, _icp_info(solution))


def _icp_info(solution: Any) -> dict[str, np.ndarray]:
    return {
        "converged": solution.converged.numpy(),
        "fitness": solution.fitness.double().numpy(),
        "inlier_rmse": solution.inlier_rmse.double().numpy(),
        "iterations": solution.iterations.numpy(),
    }


def _run_open3d_icp(
    template: np.ndarray, source: np.ndarray, mask: np.ndarray | None, options: dict
) -> _Run:
    parts = []
    for i in range(template.shape[0]):
        target = template[i] if mask is None else template[i][mask[i]]
        try:
            parts.append(open3d_icp(source[i], target, **options))
        except (ValueError, TypeError) as exc:
            raise MaskNetError(f"open3d-icp: {exc}") from exc
    solution = type(parts[0])(*(torch.cat(field_parts) for field_parts in zip(*parts, strict=True)))
    return _Run(solution.transform.double().numpy(), _icp_info(solution))


@torch.inference_mode()
def _run_network(
    template: np.ndarray, source: np.ndarray, mask: np.ndarray | None, options: dict
) -> _Run:
    """A learned network on each pair's template points in use (all, or the masked ones)."""
    network = options["network"]
    if mask is None or len(set(mask.sum(1).tolist())) == 1:
        # Every pair keeps the same number of points (top-k masks): one batched call.
        index = None if mask is None else np.stack([np.flatnonzero(m) for m in mask])
        return _network_batch(network, template, source, index, options)
    parts = [  # threshold masks: sizes differ, so pair by pair
        _network_batch(network, template[i : i + 1], source[i : i + 1], idx[None], options)
        for i, idx in enumerate(np.flatnonzero(m) for m in mask)
    ]
    inliers = (
        None
        if parts[0].correspondence_inliers is None
        else np.concatenate([p.correspondence_inliers for p in parts])
    )
    info = {key: np.concatenate([p.info[key] for p in parts]) for key in parts[0].info}
    return _Run(np.concatenate([p.transform for p in parts]), info, inliers)


def _network_batch(
    network: torch.nn.Module,
    template: np.ndarray,
    source: np.ndarray,
    index: np.ndarray | None,
    options: dict,
) -> _Run:
    """Run ``network`` on template[:, index] (B, K, 3) and source (B, M, 3), scaled to unit
    radius; clouds above the network's ``input_points`` are farthest-point sampled first."""
    b = template.shape[0]
    index = (
        np.broadcast_to(np.arange(template.shape[1]), template.shape[:2])
        if index is None
        else index
    )
    if index.shape[1] < MIN_POINTS:
        raise MaskNetError(
            f"the mask kept {index.shape[1]} template point(s); a registration network needs "
            f"at least {MIN_POINTS} (lower the threshold, or use top-k)"
        )
    limit = getattr(network, "config", {}).get("input_points")
    n_used, m = index.shape[1], source.shape[1]
    if limit and (n_used > limit or m > limit):
        n_keep = min(n_used, limit)
        m_keep = min(m, limit, max(3, round(m * n_keep / n_used)))  # same overlap ratio
        index = np.stack(
            [
                index[i][farthest_point_sample(template[i, index[i]], n_keep).indices]
                for i in range(b)
            ]
        )
        source = np.stack(
            [source[i][farthest_point_sample(source[i], m_keep).indices] for i in range(b)]
        )
    tpl = torch.from_numpy(template).float()
    # The networks saw unit-radius shapes: scale each pair by its template's radius.
    radius = unit_radius(tpl)[:, None, None]
    used = torch.gather(tpl, 1, torch.from_numpy(np.array(index))[..., None].expand(-1, -1, 3))
    device = next(network.parameters()).device
    kwargs = {"max_iterations": options["max_iterations"]}
    if "tolerance" in options:
        kwargs["tolerance"] = options["tolerance"]
    was_training = network.training
    network.eval()  # e.g. PRNet samples Gumbel noise in training mode
    try:
        solution = network(
            (used / radius).to(device),
            (torch.from_numpy(source).float() / radius).to(device),
            **kwargs,
        )
    finally:
        network.train(was_training)
    transform = solution.transform.double().cpu().numpy()
    transform[:, :3, 3] *= radius[:, 0].double().numpy()
    info = {"iterations": solution.iterations.cpu().numpy()}
    if hasattr(solution, "converged"):  # PointNetLK
        info["converged"] = solution.converged.cpu().numpy()
        info["feature_residual"] = solution.residual.double().cpu().numpy()
    inliers = None
    weight = getattr(solution, "template_weight", None)
    if weight is not None:
        inliers = np.zeros(template.shape[:2], bool)
        np.put_along_axis(inliers, index, (weight >= 0.5).cpu().numpy(), axis=1)
    return _Run(transform, info, inliers)


def _run_open3d_global(method: str):
    from masknet.registration.open3d_global import open3d_fgr, open3d_fpfh_ransac

    solver = open3d_fpfh_ransac if method == "open3d-ransac" else open3d_fgr

    def run(
        template: np.ndarray, source: np.ndarray, mask: np.ndarray | None, options: dict
    ) -> _Run:
        options = dict(options)
        relative_voxel = options.pop("voxel_size", 0.05)
        transforms, fitness, rmse = [], [], []
        for i in range(template.shape[0]):
            target = template[i] if mask is None else template[i][mask[i]]
            radius = float(unit_radius(torch.from_numpy(template[i][None]))[0])
            tf, fit, err = solver(source[i], target, voxel_size=relative_voxel * radius, **options)
            transforms.append(tf)
            fitness.append(fit)
            rmse.append(err)
        info = {
            "fitness": np.asarray(fitness),
            "inlier_rmse": np.asarray(rmse),
            "converged": np.zeros(len(fitness), bool),
            "iterations": np.full(len(fitness), -1),
        }
        return _Run(np.stack(transforms), info)

    return run


_METHOD_RUNNERS: dict[str, Callable[[np.ndarray, np.ndarray, np.ndarray | None, dict], _Run]] = {
    "icp": _run_icp,
    "open3d-icp": _run_open3d_icp,
    **{name: _run_network for name in NETWORK_METHODS},
    "open3d-ransac": _run_open3d_global("open3d-ransac"),
    "open3d-fgr": _run_open3d_global("open3d-fgr"),
}
