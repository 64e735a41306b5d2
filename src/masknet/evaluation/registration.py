"""Seeded registration benchmark: X against Mask-X on the same pairs.

Each pipeline is a set of keyword arguments for :func:`masknet.register`, run pair by
pair (batch 1, as a user calls it), so the times are per-pair latencies. Errors
are against each pair's ground-truth transform (source -> template):

* rotation error: the angle of R_est^T R_true, in degrees;
* translation error: ||t_est - t_true||, in the shapes' units (unit radius for
  ModelNet40).
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Mapping

import numpy as np

from masknet._extras import progress_bar
from masknet.data.pairs import Pairs
from masknet.errors import MaskNetError
from masknet.geometry.se3 import rotation_angle_deg
from masknet.models.masknet import PAIRS_PER_CALL
from masknet.registration.api import register
from masknet.registration.terms.methods import METHOD_TITLES

__all__ = [
    "PIPELINES",
    "x_and_mask_x",
    "pair_arrays",
    "pose_errors",
    "summarize_errors",
    "error_summary",
    "batched_errors",
    "time_pipeline",
    "benchmark_registration",
    "iteration_errors",
    "paired_difference",
]


def x_and_mask_x(methods: Iterable[str] | Mapping[str, str], **kwargs: object) -> dict[str, dict]:
    """Pipelines ``X`` and ``Mask-X`` for each method, as :func:`register` keyword arguments.

    ``methods``: method names of :func:`register` (titled by ``METHOD_TITLES``), or a
    mapping title -> method name. ``kwargs`` are added to every pipeline.
    """
    titled = methods if isinstance(methods, Mapping) else {METHOD_TITLES[m]: m for m in methods}
    pipelines = {}
    for title, method in titled.items():
        pipelines[title] = {"method": method, "use_mask": False, **kwargs}
        pipelines[f"Mask-{title}"] = {"method": method, "use_mask": True, **kwargs}
    return pipelines


# The rows of the registration table; the paper's budget of 10 iterations throughout.
PIPELINES: dict[str, dict] = {
    **x_and_mask_x(["icp", "pointnetlk"]),
    "Mask-ICP, 3 rounds": {"method": "icp", "use_mask": True, "iterations": 3},
    "Mask-ICP + 10 ICP refine": {"method": "icp", "use_mask": True, "refine_iterations": 10},
    "ICP, 20 iterations": {"method": "icp", "use_mask": False, "max_iterations": 20},
    "Open3D ICP": {"method": "open3d-icp", "use_mask": False},
    "Open3D RANSAC (FPFH)": {"method": "open3d-ransac", "use_mask": False},
    "Open3D FGR (FPFH)": {"method": "open3d-fgr", "use_mask": False},
}


def pair_arrays(pairs: Pairs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Float64 numpy template (P, N, 3), source (P, M, 3) and true transform (P, 4, 4)."""
    return (
        pairs.template.double().numpy(),
        pairs.source.double().numpy(),
        pairs.transform.double().numpy(),
    )


def pose_errors(estimate: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation errors (degrees) and translation errors of (P, 4, 4) transforms, (P,) each;
    single (4, 4) transforms give () each."""
    estimate, truth = np.asarray(estimate, np.float64), np.asarray(truth, np.float64)
    if estimate.shape != truth.shape or estimate.shape[-2:] != (4, 4) or estimate.ndim > 3:
        raise MaskNetError(
            f"pose_errors takes two (4, 4) or (P, 4, 4) transforms of one shape, got "
            f"{estimate.shape} and {truth.shape}"
        )
    rotation = rotation_angle_deg(np.swapaxes(estimate[..., :3, :3], -1, -2) @ truth[..., :3, :3])
    translation = np.linalg.norm(estimate[..., :3, 3] - truth[..., :3, 3], axis=-1)
    return rotation, translation


def summarize_errors(rotation: np.ndarray, translation: np.ndarray) -> dict[str, float]:
    """Mean, median and RMSE of rotation (degrees) and translation errors."""
    out = {}
    for name, e in (("rot", rotation), ("trans", translation)):
        out[f"{name}_mean"] = float(e.mean())
        out[f"{name}_median"] = float(np.median(e))
        out[f"{name}_rmse"] = float(np.sqrt(np.mean(e**2)))
    return out


def paired_difference(
    errors: np.ndarray, base: np.ndarray, name: str = "paired_diff"
) -> dict[str, float]:
    """Mean of ``errors - base`` ((P,) each, the same pairs) as ``name``, and its standard
    error as ``paired_se``."""
    diff = np.asarray(errors, np.float64) - np.asarray(base, np.float64)
    return {name: float(diff.mean()), "paired_se": float(diff.std(ddof=1) / np.sqrt(len(diff)))}


def error_summary(estimate: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """:func:`summarize_errors` of the :func:`pose_errors` of (P, 4, 4) estimates."""
    return summarize_errors(*pose_errors(estimate, truth))


def batched_errors(pairs: Pairs, chunk: int = PAIRS_PER_CALL, **kwargs: object) -> dict[str, float]:
    """Errors of one pipeline (``kwargs`` for :func:`register`) over every pair, in
    batched register calls of ``chunk`` pairs."""
    template, source, truth = pair_arrays(pairs)
    estimates = [
        register(template[i : i + chunk], source[i : i + chunk], **kwargs).transform
        for i in range(0, len(template), chunk)
    ]
    return error_summary(np.concatenate(estimates), truth)


def time_pipeline(
    pairs: Pairs, repeats: int, warmup: int = 5, **kwargs: object
) -> dict[str, float]:
    """Median wall time (ms) of single-pair :func:`register` calls, cycling over the pairs,
    with the median time of each stage."""
    template, source, _ = pair_arrays(pairs)
    totals, stages = [], {"mask": [], "register": []}
    for call in range(warmup + repeats):
        i = call % len(template)
        start = time.perf_counter()
        result = register(template[i], source[i], **kwargs)
        elapsed = time.perf_counter() - start
        if call >= warmup:
            totals.append(elapsed)
            for key, values in stages.items():
                values.append(result.times[key])
    return {
        "ms_per_pair": 1e3 * float(np.median(totals)),
        **{f"ms_{key}": 1e3 * float(np.median(values)) for key, values in stages.items()},
    }


def benchmark_registration(
    pairs: Pairs,
    pipelines: Mapping[str, dict] | None = None,
    progress: bool = True,
    **common: object,
) -> dict[str, dict[str, float]]:
    """Run every pipeline on every pair; returns name -> errors and times.

    Args:
        pairs: the seeded test pairs (template (P, N, 3), source (P, M, 3), transform).
        pipelines: name -> :func:`register` keyword arguments (default :data:`PIPELINES`).
        **common: keyword arguments added to every call (e.g. ``model=``).

    Returns:
        name -> {rot_mean, rot_median, rot_rmse (degrees), trans_mean, trans_median,
        trans_rmse, ms_per_pair (mean wall time of the call), ms_mask, ms_register,
        ms_refine (mean per stage)}.
    """
    pipelines = PIPELINES if pipelines is None else pipelines
    template, source, truth = pair_arrays(pairs)
    rows = {}
    for name, kwargs in pipelines.items():
        estimates = np.empty_like(truth)
        stage = {"total": 0.0, "mask": 0.0, "register": 0.0, "refine": 0.0}
        register(template[0], source[0], **kwargs, **common)  # warm-up: loads, caches
        for i in progress_bar(range(len(truth)), desc=name, disable=not progress, mininterval=1):
            result = register(template[i], source[i], **kwargs, **common)
            estimates[i] = result.transform
            for key in stage:
                stage[key] += result.times[key]
        rows[name] = error_summary(estimates, truth)
        rows[name].update(
            {
                f"ms_{k}" if k != "total" else "ms_per_pair": 1e3 * v / len(truth)
                for k, v in stage.items()
            }
        )
    return rows


def iteration_errors(
    pairs: Pairs, rounds: int = 3, progress: bool = True, **kwargs: object
) -> list[dict[str, float]]:
    """Errors after each round of {mask -> register -> move the source} (one call per pair).

    Returns one row per round: ``round`` and the :func:`summarize_errors` keys.
    """
    template, source, truth = pair_arrays(pairs)
    per_round = np.empty((rounds, *truth.shape))
    for i in progress_bar(
        range(len(truth)), desc=f"{rounds} rounds", disable=not progress, mininterval=1
    ):
        result = register(template[i], source[i], iterations=rounds, **kwargs)
        per_round[:, i] = np.stack(result.rounds)
    return [{"round": r + 1, **error_summary(per_round[r], truth)} for r in range(rounds)]
